"""The demo's figures, drawn from synthetic episode traces: the slip-stop figure zooms on
the stop, and no title or label of the slip-track figure overlaps another."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks import demo_plots

OBJECTS = ("chips_can", "pla_rod")
METHODS = ("aslip", "svm")


def _episode(task: str, k: int) -> dict:
    t = np.linspace(0.0, 6.0, 601)
    push = np.where(t < 2.0, -50.0 * t, -100.0 + 55.0 * (t - 2.0)) * 1e-3
    push = np.minimum(push, (8.0 + k) * 1e-3)          # stops 8-9 mm past the contact
    tcp = np.zeros((t.size, 3))
    tcp[:, 0] = push
    obj = tcp + [0.0, 0.002, 0.0]
    return {"t": t, "tcp": tcp, "object": obj, "push_dir": np.array([1.0, 0.0, 0.0]),
            "rel": obj - tcp + 1e-3 * np.sin(t)[:, None], "v_rel": np.zeros((t.size, 2)),
            "pred_t": t, "pred_v": np.zeros((t.size, 2)), "pred_p": np.zeros(t.size)}


@pytest.fixture
def figures(tmp_path, monkeypatch):
    (tmp_path / "episodes").mkdir()
    results = []
    for task in ("slip_stop", "slip_track"):
        for m in METHODS:
            for k, obj in enumerate(OBJECTS):
                np.savez(tmp_path / "episodes" / f"{task}-{m}-{obj}-00.npz", **_episode(task, k))
                results.append({"task": task, "method": m, "object": obj, "trial": 0})
    figs = {}
    save = demo_plots._save

    def keep(fig, path):
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        FigureCanvasAgg(fig).draw()
        figs[path.name] = fig
        return save(fig, path)
    monkeypatch.setattr(demo_plots, "_save", keep)
    written = demo_plots.make_plots(tmp_path, results)
    assert all(p.is_file() for p in written)
    return figs


def test_slip_stop_zooms_on_the_stop(figures):
    fig = figures["slip_stop_trajectories.png"]
    zoom = [ax for ax in fig.axes if ax.get_title().startswith("the stop")]
    assert len(zoom) == len(METHODS)
    for ax in zoom:
        lo, hi = ax.get_ylim()
        assert lo <= 8.0 and 9.0 <= hi and hi - lo < 20.0   # mm around the stop, not 100
        assert ax.get_xlim()[1] == pytest.approx(6.0)


def _overlaps(a, b) -> bool:
    return a.width > 0 and b.width > 0 and a.overlaps(b)


def test_no_text_of_the_slip_track_figure_overlaps_another(figures):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    fig = figures["slip_track_trajectories.png"]
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    r = canvas.get_renderer()
    texts = [t for ax in fig.axes for t in (ax.title, ax.xaxis.label, ax.yaxis.label)
             if t.get_text()]
    boxes = [t.get_window_extent(r) for t in texts]
    for i in range(len(boxes)):
        for j in range(i + 1, len(boxes)):
            assert not _overlaps(boxes[i], boxes[j]), (texts[i].get_text(), texts[j].get_text())


def test_the_pivot_figure_shows_each_arms_angle(tmp_path):
    """One column per arm, the angle turned in degrees; no figure without the scene's angle."""
    (tmp_path / "episodes").mkdir()
    t = np.linspace(0.0, 6.0, 601)
    results = []
    for arm, final_deg in (("rotation_aware", 3.0), ("ignores_rotation", 30.0)):
        angle = np.radians(np.clip((t - 4.0) * 40.0, 0.0, final_deg))
        np.savez(tmp_path / "episodes" / f"pivot_stop-aslip-{arm}-chips_can-00.npz",
                 t=t, angle=angle, w_rel=np.gradient(angle, t), pred_t=t,
                 pred_w=np.gradient(angle, t))
        results.append({"task": "pivot_stop", "method": "aslip", "arm": arm,
                        "object": "chips_can", "trial": 0})
    written = demo_plots.make_plots(tmp_path, results)
    assert [p.name for p in written] == ["pivot_stop_angle.png"] and written[0].is_file()
    for f in (tmp_path / "episodes").glob("*.npz"):
        f.unlink()
    assert demo_plots.make_plots(tmp_path, results) == []
