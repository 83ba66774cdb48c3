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


def test_the_calibration_fit_reads_the_grasps_from_disk_and_fits_what_it_would_in_memory(
        tmp_path, monkeypatch):
    """``make scale`` measured the fit at 5.0 GiB on 16 hours of audio: it held every
    training grasp's frames, and their float64 common-mode rows. The frames now go to a
    temporary file the fit reads grasp by grasp; the constants are those of the in-memory
    fit (to rounding: the moments merge grasp by grasp)."""
    from aslip_ros.learn.calibration import frames as cal_frames
    from aslip_ros.learn.calibration import grasp
    ds = _dataset(tmp_path)
    fcfg = FeatureConfig(n_mels=32)
    rows = np.arange(len(ds))
    seen = []
    fit = grasp.fit_constants

    def spy(frames, labels, *a, **k):
        seen.append([frames[i] for i in range(len(frames))])
        return fit(frames, labels, *a, **k)
    monkeypatch.setattr(cal_frames, "fit_constants", spy)
    spilled = cal_frames.fit_on_dataset(ds, rows, ds.channel_names, fcfg)
    assert seen and all(isinstance(f, np.memmap) for f in seen[0])
    monkeypatch.undo()
    cutter = cal_frames.FrameCutter(fcfg, ds.sample_rate)
    held, labels = [], []
    for t in np.unique(ds.windows["trial"]):
        r = np.flatnonzero(ds.windows["trial"] == t)
        held.append(cutter.frames(np.asarray(ds.audio(int(t)))))
        labels.append(cal_frames.frame_slip_from_windows(
            held[-1].shape[2], cutter, ds.windows["start"][r], ds.window_samples, ds.slip(r)))
    for got, frames in zip(seen[0], held):
        np.testing.assert_array_equal(np.asarray(got), frames)
    in_memory = grasp.fit_constants(held, labels, list(ds.channel_names), cutter.hop_s)
    a, b = spilled.to_dict(), in_memory.to_dict()
    assert a.keys() == b.keys()
    for key in a:
        if isinstance(a[key], float) or (isinstance(a[key], (list, tuple)) and a[key]
                                         and isinstance(a[key][0], float)):
            np.testing.assert_allclose(a[key], b[key], rtol=1e-9, atol=1e-12, err_msg=key)
        else:
            assert a[key] == b[key], key


def test_moments_merged_grasp_by_grasp_are_those_of_all_rows():
    from aslip_ros.learn.calibration.grasp import _Moments
    rng = np.random.default_rng(0)
    parts = [rng.normal(5.0, 2.0, (n, 3)) for n in (1, 0, 40, 7, 300)]
    m = _Moments()
    for p in parts:
        m.add(p)
    whole = np.concatenate(parts)
    np.testing.assert_allclose(m.mean, whole.mean(axis=0), rtol=1e-12)
    np.testing.assert_allclose(m.std, whole.std(axis=0), rtol=1e-12)
