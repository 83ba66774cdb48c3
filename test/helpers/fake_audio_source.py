"""A test-only audio source, loaded by ``audio_capture`` as
``source:=fake_audio_source:open_fake`` (test/helpers is on the node processes' path).

It shows everything a new source needs: an object with ``sample_rate``, ``channel_names``,
``start``, ``read`` and ``stop`` (:class:`aslip_ros.hw.audio_source.AudioSource`), and a
factory that opens it from the node's parameters. Block ``k`` holds the value ``k / 1000``
in channel 0 and its negative in channel 1, so the test can tell every block apart.
"""

from __future__ import annotations

import time

import numpy as np

from aslip_ros.hw.audio_block import AudioBlock
from aslip_ros.hw.audio_source import OpenedSource

RATE = 8000.0
BLOCK = 80
NAMES = ["fake_left", "fake_right"]


class FakeSource:
    """A finite, paced two-channel stream of ``n_blocks`` blocks."""

    def __init__(self, n_blocks: int) -> None:
        self.sample_rate = RATE
        self.channel_names = list(NAMES)
        self.finished = False
        self._n = n_blocks
        self._k = 0

    def start(self) -> None:
        """Nothing to open."""

    def read(self, timeout_s=None):
        """Next block, one block length after the previous one; None after the last."""
        if self._k >= self._n:
            self.finished = True
            return None
        time.sleep(BLOCK / RATE)
        value = self._k / 1000.0
        data = np.tile(np.array([[value, -value]], dtype=np.float32), (BLOCK, 1))
        t = time.time()
        block = AudioBlock(self._k * BLOCK, t, t, data)
        self._k += 1
        return block

    def stop(self) -> None:
        """Nothing to release."""


def open_fake(params, node=None):
    """The factory ``audio_capture`` calls with its parameter values."""
    n_blocks = int(params["channels"]) * 10          # any parameter may configure a source
    meta = {"format": "aslip-metadata", "version": 1, "sample_rate": RATE,
            "channel_names": NAMES, "source": "fake"}
    return OpenedSource(FakeSource(n_blocks), meta, layout="fake2", finite=False)


class FlakySource(FakeSource):
    """Fails its first ``start`` as PortAudio does when an interface is slow to deliver its
    first period; starts on the next."""

    def __init__(self, n_blocks: int) -> None:
        super().__init__(n_blocks)
        self.starts = 0

    def start(self) -> None:
        """Refused once, then started."""
        self.starts += 1
        if self.starts == 1:
            raise RuntimeError("Error starting stream: Wait timed out [PaErrorCode -9987]")


def open_flaky(params, node=None):
    """``source:=fake_audio_source:open_flaky``."""
    meta = {"format": "aslip-metadata", "version": 1, "sample_rate": RATE,
            "channel_names": NAMES, "source": "flaky"}
    return OpenedSource(FlakySource(1000), meta, layout="fake2", finite=False)
