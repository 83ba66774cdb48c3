"""From audio to estimates: the window predictor, the streaming predictor, the stream gate
and ring buffer, the dead-channel check, and the one live estimator (``live``)."""
