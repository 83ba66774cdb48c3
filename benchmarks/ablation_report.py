"""The ablation's report: the paper's qualitative claims checked on our rows, and the
Markdown of Tables I and II and of the robot-noise comparison."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

from aslip_ros.util import read_json

from .common import fmt_num, fmt_pm, markdown_table


def orderings(table: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The paper's qualitative claims, checked on our rows (a claim with a missing row is
    reported as ``None``)."""
    rows = {r["key"]: r["ours"] for r in table}
    scene = {r["key"]: scene_of(r) for r in table}

    def get(key: str, metric: str) -> float | None:
        return rows.get(key, {}).get(metric)

    def chain(keys: list[str], metric: str, increasing: bool) -> dict[str, Any]:
        vals = [get(k, metric) for k in keys]
        ok, note = None, None
        if all(k in scene for k in keys) and len({scene[k] for k in keys}) > 1:
            note = "rows measured on different scene versions"
        elif all(v is not None for v in vals):
            ok = all((a < b) if increasing else (a > b) for a, b in zip(vals, vals[1:]))
        return {"rows": keys, "metric": metric, "values": vals, "holds": ok, "note": note}

    checks = []
    lay = ["ft_4mic", "ft_2mic_corners", "ft_2mic_same_finger", "ft_2mic_centered"]
    checks.append({"claim": "direction: 4-mic < corners < same-finger < centered (finetuned)",
                   **chain(lay, "dir_mae_deg", True)})
    checks.append({"claim": "detection: 4-mic > corners, same-finger > centered (finetuned)",
                   **chain(["ft_4mic", "ft_2mic_corners", "ft_2mic_centered"], "det_pct",
                           False)})
    for lay_name in ("4mic", "2mic_centered", "2mic_corners", "2mic_same_finger"):
        for metric in ("dir_mae_deg", "det_pct"):
            c = chain([f"ft_{lay_name}", f"pre_{lay_name}"], metric, metric == "dir_mae_deg")
            checks.append({"claim": f"finetuned better than pretrain-only ({lay_name}, "
                                    f"{metric})", **c})
    checks.append({"claim": "longer windows raise detection (100 < 200 < 300 ms)",
                   **chain(["w100", "w200", "w300"], "det_pct", True)})
    checks.append({"claim": "longer windows worsen direction (100 < 200 < 300 ms MAE)",
                   **chain(["w100", "w200", "w300"], "dir_mae_deg", True)})
    checks.append({"claim": "single mic: pretrain + finetune better direction than scratch",
                   **chain(["1mic_finetune", "1mic_scratch"], "dir_mae_deg", True)})
    checks.append({"claim": "4-mic finetuned better direction than the SVM",
                   **chain(["ft_4mic", "svm"], "dir_mae_deg", True)})
    checks.append({"claim": "4-mic finetuned better detection than the SVM",
                   **chain(["ft_4mic", "svm"], "det_pct", False)})
    for base in ("plain_cnn", "plain_svm"):
        checks.append({"claim": f"4-mic finetuned better detection than the {base}",
                       **chain(["ft_4mic", base], "det_pct", False)})
        checks.append({"claim": f"4-mic finetuned better direction than the {base}",
                       **chain(["ft_4mic", base], "dir_mae_deg", True)})
        checks.append({"claim": f"4-mic finetuned better magnitude than the {base}",
                       **chain(["ft_4mic", base], "mag_rmse_mm", True)})
    return checks


def scene_of(row: dict[str, Any]) -> Any:
    """The scene version a row was measured on (None: not recorded)."""
    return (row.get("measured") or {}).get("scene_version")


def _ci(row: dict[str, Any]) -> str:
    ci = row.get("ci95") or {}
    parts = []
    for col, nd in (("det_pct", 1), ("dir_mae_deg", 1), ("mag_rmse_mm", 2)):
        lo_hi = ci.get(col)
        parts.append("–" if not lo_hi else f"[{lo_hi[0]:.{nd}f}, {lo_hi[1]:.{nd}f}]")
    return " / ".join(parts)


def _measured(row: dict[str, Any]) -> str:
    m = row.get("measured") or {}
    if not m:
        return "–"
    return f"v{m.get('scene_version')}, {m.get('date')}"


def table_markdown(result: dict[str, Any]) -> str:
    hdr = ["Method", "Det. % (paper)", "Det. % (ours)", "Dir. MAE deg (paper)",
           "Dir. MAE deg (ours)", "Mag. RMSE mm (paper)", "Mag. RMSE mm (ours)",
           "95 % CI det. / dir. / mag. (ours)", "chance det. %",
           "test windows (slip) / trials", "scene, measured"]
    body = []
    for r in result["rows"]:
        p, o = r["paper"], r["ours"]
        body.append([r["label"], fmt_num(p["det_pct"]), fmt_num(o.get("det_pct")),
                     fmt_pm(p["dir_mae_deg"], p["dir_std_deg"]),
                     fmt_pm(o.get("dir_mae_deg"), o.get("dir_std_deg")),
                     fmt_pm(p["mag_rmse_mm"], p["mag_std_mm"]),
                     fmt_pm(o.get("mag_rmse_mm"), o.get("mag_std_mm"), 2),
                     _ci(r), fmt_num(r.get("majority_det_pct")),
                     f"{o.get('n_windows')} ({o.get('n_slip')}) / "
                     f"{r.get('n_test_trials') or '–'}", _measured(r)])
    text = ["# Table I on the scene\n",
            "Ours: externally induced set, held-out test split (by trial); 95 % CI: "
            "bootstrap over the test trials. Chance det. = always answering the majority "
            "class. Plain CNN / plain SVM: the untuned baselines of `learn.baselines` (the "
            "paper has no such rows). Rows measured on different scene versions are not "
            "comparable with each other.\n", markdown_table(hdr, body),
            "\n## The paper's orderings\n"]
    for c in result["checks"]:
        mark = {True: "holds", False: "**does not hold**",
                None: c.get("note") or "not run"}[c["holds"]]
        vals = ", ".join(fmt_num(v) for v in c["values"])
        text.append(f"- {c['claim']}: {mark} ({vals})\n")
    text.append(f"\nProtocol: `{result['protocol']}`; run time "
                f"{(result['elapsed_s'] or 0) / 60:.1f} min.\n")
    return "".join(text)


def per_object_markdown(per_obj: dict[str, Any]) -> str:
    hdr = ["Object", "Train", "Det. % (paper)", "Det. % (ours)", "Dir. MAE deg (paper)",
           "Dir. MAE deg (ours)", "Mag. RMSE mm (paper)", "Mag. RMSE mm (ours)", "n (slip)"]
    body = []
    for obj, e in per_obj.items():
        for k, name in (("per_object", "Per-obj."), ("all_object", "All-obj.")):
            p = e.get("paper", {}).get(k, {})
            o = e.get(k, {})
            body.append([obj, name, fmt_num(p.get("det_pct")), fmt_num(o.get("det_pct")),
                         fmt_pm(p.get("dir_mae_deg"), p.get("dir_std_deg"), 2),
                         fmt_pm(o.get("dir_mae_deg"), o.get("dir_std_deg"), 2),
                         fmt_pm(p.get("mag_rmse_mm"), p.get("mag_std_mm"), 2),
                         fmt_pm(o.get("mag_rmse_mm"), o.get("mag_std_mm"), 2),
                         f"{o.get('n_windows', '–')} ({o.get('n_slip', '–')})"])
    notes = [f"- {obj}: {e['note']}\n" for obj, e in per_obj.items() if e.get("note")]
    return ("# Table II on the scene (4 microphones, finetuned)\n\n"
            "Per-obj.: heads finetuned on that object only; All-obj.: the Table I model. Both "
            "on the object's test trials.\n\n" + markdown_table(hdr, body)
            + ("\n" + "".join(notes) if notes else ""))


def robot_noise_markdown(robot: dict[str, Any]) -> str:
    hdr = ["Layout", "Dir. MAE deg (paper)", "Dir. MAE deg (ours)", "Mag. RMSE mm (paper)",
           "Mag. RMSE mm (ours)", "Det. % (ours)", "dir. increase vs external % (ours)"]
    body = []
    for lay, e in robot.items():
        p, o = e.get("paper") or {}, e["robot_val"]
        body.append([lay, fmt_pm(p.get("dir_mae_deg"), p.get("dir_std_deg")),
                     fmt_pm(o.get("dir_mae_deg"), o.get("dir_std_deg")),
                     fmt_pm(p.get("mag_rmse_mm"), p.get("mag_std_mm")),
                     fmt_pm(o.get("mag_rmse_mm"), o.get("mag_std_mm"), 2),
                     fmt_num(o.get("det_pct")), fmt_num(e.get("dir_increase_pct"))])
    return ("# Slip with robot noise\n\nFinetuned models on the robot-induced validation "
            "split (the arm moves; audio holds slip and robot noise). Paper increases: 4-mic "
            "+12.8 %, centered +92.2 %, corners +17.7 %, same finger -8.4 %.\n\n"
            + markdown_table(hdr, body))


def bootstrap_intervals(trial, prob, raw_v, true_v, slip, window_s: float, n_boot: int,
                        seed: int) -> dict[str, Any]:
    """The ``*_ci`` intervals of ``learn.stats.bootstrap_metrics`` and the number of test
    trials (no intervals from a single trial)."""
    import numpy as np
    from aslip_ros.learn.stats import bootstrap_metrics
    n = int(np.unique(np.asarray(trial)).size)
    if n < 2:
        return {"n_trials": n}
    res = bootstrap_metrics(trial, prob, raw_v, true_v, slip, window_s, n_boot=n_boot,
                            seed=seed)
    return {"n_trials": n, **{k: v for k, v in res.items() if k.endswith("_ci")}}


#: Interval keys of ``learn.stats`` -> (the paper's column, factor to its units).
CI_COLUMNS = {"detection_accuracy_ci": ("det_pct", 100.0),
              "direction_mae_deg_ci": ("dir_mae_deg", 1.0),
              "magnitude_rmse_mm_ci": ("mag_rmse_mm", 1.0)}


def merge_rows(keys: Sequence[str], previous: Path | None,
               measured: dict[str, dict[str, Any]]) -> list[dict[str, Any]]:
    """Table I's rows in the order of ``keys``: the ones measured now, and (``previous``,
    an earlier ``table.json``) the earlier rows this run did not measure, unchanged."""
    old: dict[str, dict[str, Any]] = {}
    if previous is not None and Path(previous).is_file():
        old = {r["key"]: r for r in read_json(previous).get("rows", [])}
    return [measured.get(k) or old[k] for k in keys if k in measured or k in old]


def pct(v: float | None) -> float | None:
    return None if v is None else round(100.0 * v, 1)


def majority(m: dict[str, Any]) -> float | None:
    """Detection accuracy of always answering the majority class (the chance level)."""
    n = m.get("n_windows") or 0
    if not n:
        return None
    frac = m.get("n_slip", 0) / n
    return round(100.0 * max(frac, 1.0 - frac), 1)


def short(o: dict[str, Any]) -> str:
    return (f"det {fmt_num(o.get('det_pct'))} %, dir {fmt_num(o.get('dir_mae_deg'))} deg, "
            f"mag {fmt_num(o.get('mag_rmse_mm'), 2)} mm")
