"""aslip_ros.learn: features, network, losses, checkpoints, SVM baseline, predictor, training.

ROS-free. Submodules are imported on demand (``from aslip_ros.learn.predictor import
Predictor``) so that importing the package stays cheap; see docs/model.md.
"""
