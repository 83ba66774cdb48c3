"""The paper's benchmarks and experiments (ablation, bench, stability, demo, transfer,
magnitude, lag, calibration, stale input): run from a checkout by the Makefile
(``python -m benchmarks.<name>``, benchmarks/cli.py), never installed with ``aslip_ros``."""
