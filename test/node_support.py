"""Helpers for the rclpy-only node tests (no tests here).

Node executables run as separate processes (the installed launchers, found on
AMENT_PREFIX_PATH), with the full parent environment and the test's isolated
ROS_DOMAIN_ID; the test process listens and publishes through its own rclpy context.
"""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path

import numpy as np

from aslip_ros.runtime.child import NodeProcess, node_exe, ros_args  # noqa: F401 - for tests


def driver_msgs(package: str):
    """``<package>.msg`` of a driver's message package (audio_common_msgs, mocap4r2_msgs):
    optional for users, so a test that needs it skips with the reason when it is not built,
    except under ``ASLIP_REQUIRE_DRIVER_MSGS=1`` (CI builds them), where it fails instead."""
    import importlib
    import os

    import pytest
    try:
        return importlib.import_module(f"{package}.msg")
    except ImportError as exc:
        why = (f"{package} is not built ({exc}): make setup with ASLIP_DRIVER_MSGS naming "
               "it builds it")
        if os.environ.get("ASLIP_REQUIRE_DRIVER_MSGS") == "1":
            pytest.fail(f"ASLIP_REQUIRE_DRIVER_MSGS=1 but {why}")
        pytest.skip(why)


def header_ns(msg) -> int:
    """A stamped message's header stamp in nanoseconds."""
    from aslip_ros.audio_frame import stamp_to_ns
    return stamp_to_ns(msg.header.stamp)


SCENE_NAMES = ["left_front_top", "left_rear_bottom", "right_front_bottom", "right_rear_top"]


def deep(qos, depth: int = 1000):
    """``qos`` with a queue ``depth`` deep: a test's reader of a stream must not be what loses
    messages when the test process is slow to take them (a 10-deep queue did, under load)."""
    from rclpy.qos import QoSProfile
    return QoSProfile(history=qos.history, depth=max(depth, qos.depth),
                      reliability=qos.reliability, durability=qos.durability)


def wait_until(predicate, timeout: float, poll_s: float = 0.02) -> bool:
    """Poll ``predicate()`` every ``poll_s`` until true or ``timeout`` seconds have passed."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(poll_s)
    return bool(predicate())


def received_block(bus, topic: str, first_sample_index: int, timeout: float = 30.0) -> bool:
    """Whether the audio block starting at ``first_sample_index`` reaches ``bus`` on
    ``topic`` in time. A source's "end of replay" line can come before its last blocks have
    crossed the transport (a loaded run closed the bus 4320 samples short)."""
    return bus.wait(lambda: any(int(m.first_sample_index) == first_sample_index
                                for m in bus.messages(topic)), timeout)


class Bus:
    """An in-process node on the test's context: subscriptions that record, publishers."""

    def __init__(self, context, name: str = "aslip_test_bus") -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        self.node = rclpy.create_node(name, context=context)
        self.got: dict[str, list] = {}
        self._lock = threading.Lock()
        self._ex = SingleThreadedExecutor(context=context)
        self._ex.add_node(self.node)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        while not self._stop.is_set():
            try:
                self._ex.spin_once(timeout_sec=0.05)
            except Exception:  # noqa: BLE001 - context shut down under us at the end
                return

    def listen(self, msg_type, topic: str, qos) -> None:
        """Record every message on ``topic``, with ``qos`` made :func:`deep` (the test's
        own queue must never be what drops a message)."""
        self.got.setdefault(topic, [])

        def cb(m, t=topic):
            with self._lock:
                self.got[t].append((time.monotonic(), m))
        self.node.create_subscription(msg_type, topic, cb, deep(qos))

    def messages(self, topic: str) -> list:
        """Messages received on ``topic`` so far."""
        with self._lock:
            return [m for _, m in self.got.get(topic, [])]

    def stamped(self, topic: str) -> list:
        """``(arrival monotonic time, message)`` pairs."""
        with self._lock:
            return list(self.got.get(topic, []))

    def clear(self, topic: str) -> None:
        """Forget what was received on ``topic``."""
        with self._lock:
            self.got[topic] = []

    def wait(self, predicate, timeout: float = 20.0) -> bool:
        """Poll ``predicate()`` until true or timeout."""
        return wait_until(predicate, timeout)

    def diagnostics(self, name_part: str) -> list:
        """Decoded ``/aslip/diagnostics`` JSON documents whose name contains ``name_part``."""
        docs = [json.loads(m.data) for m in self.messages("/aslip/diagnostics")]
        return [d for d in docs if name_part in d["name"]]

    def latest_diagnostics(self, name_part: str, predicate=lambda v: True,
                           timeout: float = 20.0):
        """The values of the newest diagnostics of ``name_part`` once they satisfy
        ``predicate`` (None if they do not in time)."""
        found = []

        def ok() -> bool:
            docs = self.diagnostics(name_part)
            if docs and predicate(docs[-1]["values"]):
                found.append(docs[-1]["values"])
                return True
            return False
        return found[-1] if self.wait(ok, timeout) else None

    #: How long :meth:`call` waits for one answer before it sends the request again [s].
    RESEND_S = 2.0

    def call(self, srv_type, name: str, request, timeout: float = 10.0):
        """The response of service ``name`` to an idempotent ``request``.

        wait_for_service only says that the server sees the client's requests; until the
        client's response reader is discovered too, the server's answer is lost (seen: a
        node's describe_parameters never answering in a CI run). So the request goes out
        again every ``RESEND_S`` until an answer comes or ``timeout`` has passed."""
        cli = self.node.create_client(srv_type, name)
        try:
            assert cli.wait_for_service(timeout_sec=timeout), f"{name}: no such service"
            deadline = time.monotonic() + timeout
            while time.monotonic() < deadline:
                fut = cli.call_async(request)
                resend = min(deadline, time.monotonic() + self.RESEND_S)
                while not fut.done() and time.monotonic() < resend:
                    time.sleep(0.02)
                if fut.done():
                    return fut.result()
                cli.remove_pending_request(fut)
            raise AssertionError(f"{name} did not answer within {timeout:g} s")
        finally:
            self.node.destroy_client(cli)

    def set_params(self, node_name: str, values: dict, timeout: float = 10.0) -> list:
        """Set parameters on a remote node; returns the SetParametersResult list."""
        from rcl_interfaces.msg import Parameter
        from rcl_interfaces.srv import SetParameters
        from rclpy.parameter import Parameter as P
        req = SetParameters.Request()
        req.parameters = [P(k, value=v).to_parameter_msg() for k, v in values.items()]
        assert all(isinstance(p, Parameter) for p in req.parameters)
        return list(self.call(SetParameters, f"/{node_name}/set_parameters", req,
                              timeout).results)

    def close(self) -> None:
        """Stop spinning and destroy the node."""
        self._stop.set()
        self._thread.join(2)
        self._ex.shutdown()
        self.node.destroy_node()


def in_process(context, name: str, params: dict | None = None):
    """Node ``name`` of the node table built in this process on ``context`` with ``params``
    as its start parameters, the way its executable builds it. Where the process is not the
    point (a parameter's check, at start or at run time) this saves a node process's start
    (3-5 s of CPU for slip_inference)."""
    import importlib

    from rclpy.parameter import Parameter

    from aslip_ros import node_table
    row = node_table.spec(name)
    cls = getattr(importlib.import_module(row.module), row.node_class)
    return cls(context=context, parameter_overrides=[
        Parameter(k, value=v) for k, v in (params or {}).items()])


def refusal(context, name: str, params: dict) -> str:
    """Why node ``name`` refuses to start with ``params`` (:func:`in_process`): the text its
    executable prints after "refused to start:" before it exits 2 (runtime/process.py,
    exercised as a process by one test per node). AssertionError when it starts."""
    from rclpy.exceptions import ParameterException

    from aslip_ros.runtime.process import ConfigError
    try:
        node = in_process(context, name, params)
    except (ConfigError, ParameterException) as exc:
        assert str(exc), f"{name} refused {params} without saying why"
        return str(exc)
    node.destroy_node()
    raise AssertionError(f"{name} started with {params}")


def set_params(node, values: dict) -> list:
    """``node.set_parameters`` of ``values``: the SetParametersResult list a remote
    ``set_parameters`` call would get (the same callbacks decide)."""
    from rclpy.parameter import Parameter
    return node.set_parameters([Parameter(k, value=v) for k, v in values.items()])


def make_checkpoint(path, channel_names=SCENE_NAMES, sample_rate: float = 48000.0,
                    window_s: float = 0.05, slip_logit: float | None = None,
                    velocity=(0.02, 0.0), seed: int = 0, angular: bool = False) -> Path:
    """A tiny untrained CNN checkpoint through the learn package's own save path (with
    ``angular``: with the rotational head, whose untrained rate is not zero).

    With ``slip_logit`` the slip head ignores the audio and says ``sigmoid(slip_logit)``, and
    the speed and direction heads output ``velocity`` (grasp plane x, z): a model whose
    answer the test knows, running through the real feature and inference code.
    """
    import torch

    from aslip_ros.learn.checkpoint import save_checkpoint
    from aslip_ros.learn.features import FeatureConfig
    from aslip_ros.learn.models.aslip_cnn import ModelConfig, SlipNet
    fc = FeatureConfig(n_mels=16, n_fft=256, hop=160)
    mc = ModelConfig(n_channels=len(channel_names), n_mels=fc.n_mels, width=4, depth=2,
                     temporal_layers=1, temporal_channels=8, gate_hidden=4, head_hidden=8,
                     speed_scale=0.02, angular=angular)
    torch.manual_seed(seed)
    net = SlipNet(mc)
    net.set_normalization(np.full(fc.n_mels, -10.0), np.full(fc.n_mels, 5.0))
    if slip_logit is not None:
        with torch.no_grad():
            speed = float(np.hypot(*velocity))
            raw = np.log(np.expm1(max(speed, 1e-6) / mc.speed_scale))   # softplus^-1
            for head, bias in (("slip", [slip_logit]), ("magnitude", [raw]),
                               ("direction", list(velocity))):
                last = net.heads[head][-1]
                last.weight.zero_()
                last.bias.copy_(torch.tensor(bias, dtype=torch.float32))
    net.eval()
    meta = {"model_type": "aslip_cnn", "model_config": mc.to_dict(),
            "feature_config": fc.to_dict(), "channel_names": list(channel_names),
            "layout": "4mic", "sample_rate": float(sample_rate), "window_s": window_s,
            "window_samples": int(round(window_s * sample_rate)), "epsilon_m_s": 0.005,
            "threshold": 0.5, "provenance": {"stage": "test fixture, untrained"}}
    if angular:
        from aslip_ros.learn.checkpoint import KNOWN_OUTPUTS
        meta["outputs"] = list(KNOWN_OUTPUTS)
    return save_checkpoint(path, meta, {k: v.detach().clone()
                                        for k, v in net.state_dict().items()})
