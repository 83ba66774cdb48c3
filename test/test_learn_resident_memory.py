"""Training's resident memory does not grow with the hours of audio (#38).

``make scale`` measured ``aslip train`` at 4.0 GiB resident on one hour of 48 kHz audio:
every trial's audio map, once read (features, calibration), stayed open with its pages,
and so did every page of the feature cache an epoch had read. The passes now drop the
audio maps as they go, and the batches open the cache's map afresh every
``Batches.REMAP_BATCHES`` reads.
"""

from __future__ import annotations

import numpy as np

from aslip_ros.learn.data_io import open_dataset
from aslip_ros.learn.features import FeatureConfig
from aslip_ros.learn.synthetic import make_synthetic_dataset


def _dataset(tmp_path):
    return open_dataset(make_synthetic_dataset(tmp_path / "ds", n_trials=4, seed=5))


def test_the_feature_and_calibration_passes_leave_no_audio_map_open(tmp_path):
    from aslip_ros.learn.calibration.frames import dataset_offsets, fit_on_dataset
    from aslip_ros.learn.training.data import feature_cache
    ds = _dataset(tmp_path)
    fcfg = FeatureConfig(n_mels=32)
    feature_cache(ds, fcfg, ds.channel_names)
    assert ds.dataset._audio == {}
    rows = np.arange(len(ds))
    k = fit_on_dataset(ds, rows, ds.channel_names, fcfg)
    assert ds.dataset._audio == {}
    dataset_offsets(ds, ds.channel_names, fcfg, k, rows)
    assert ds.dataset._audio == {}
    ds.audio(0)
    assert list(ds.dataset._audio) == [0]       # a read opens the map again


def test_the_batches_open_the_feature_cache_afresh_as_they_read(tmp_path):
    from aslip_ros.learn.training.data import Batches, feature_cache
    ds = _dataset(tmp_path)
    feats = feature_cache(ds, FeatureConfig(n_mels=32), ds.channel_names)
    batches = Batches(feats, ds)
    b = np.arange(min(8, len(ds)))
    maps = set()
    for _ in range(2 * Batches.REMAP_BATCHES):
        x = batches.x(b)
        maps.add(id(batches.feats))
    assert len(maps) >= 2
    np.testing.assert_array_equal(x, np.asarray(feats[b], dtype=np.float32))
