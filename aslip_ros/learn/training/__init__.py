"""Training: the run's config (``config``), batches (``data``), the epoch loop (``loop``), the
losses, the stages (``train``), the recipe chosen on the user's data (``recipes``), the
streaming estimator's trainer (``stream``) and ``aslip train`` (``cli``)."""
