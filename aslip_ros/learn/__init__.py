"""aslip_ros.learn: from windows of audio to slip estimates, ROS-free (docs/design.md).

By role, bottom up:

- ``features`` (log-mel, the one feature path), ``incremental_features`` (the same, hop by
  hop), ``compat`` (does a checkpoint fit a stream), ``data_io`` (a dataset as training and
  evaluation read it), ``metrics`` (the paper's metrics and the rotational ones);
- ``models/``: the registry of model types (``registry``) and one module per built-in type
  holding its config, network and backend (``aslip_cnn``, ``svm``, ``aslip_stream``);
- ``calibration/``: the per-grasp microphone levels (``grasp``, ``frames``) and the
  calibrated outputs, threshold, direction sigma and angular sigma (``output``);
- ``checkpoint``: the self-describing file format, checked through the registry;
- ``inference/``: the window and streaming predictors, and the one live estimator
  (``live.LiveEstimator``) that ``slip_inference``, evaluation and the demo share;
- ``training/``: what a run is asked for (``config``), batches, the epoch loop, the stages
  (``train``), the recipe chosen on the user's data (``recipes``), the streaming trainer
  and ``aslip train`` (``cli``);
- ``evaluate`` (``aslip evaluate``), ``stats`` (trial bootstrap), ``baselines``.

Submodules are imported on demand so that importing the package stays cheap.
"""
