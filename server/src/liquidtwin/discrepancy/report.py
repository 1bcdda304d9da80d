"""Write a discrepancy report: report.json (the contract), report.md (tables) and PNG plots
(IOU over time before/after, residual maps, candidate ranking), plus model.json — the
extended model as a file a session can load."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .model import model_from_dict, save_model
from .residuals import MIN_CELLS


def _fmt(v, nd=3) -> str:
    if v is None:
        return "—"
    if isinstance(v, float):
        return f"{v:.{nd}g}" if abs(v) < 1e-2 and v != 0 else f"{v:.{nd}f}"
    if isinstance(v, (list, tuple)):
        return "(" + ", ".join(_fmt(x, nd) for x in v) + ")"
    return str(v)


def _null_cell(c: dict) -> str:
    if "null_gains" in c:
        fitted = c.get("null_fitted")
        return _fmt(c["null_gains"]) + (f", fitted {_fmt(fitted)}" if fitted else "")
    return f"not fitted: {c['null_skipped']}" if "null_skipped" in c else ""


def _ref_kind(report: dict) -> str:
    return (report.get("reference") or {}).get("kind", "base")


def _reference_line(report: dict) -> str:
    r = report.get("reference")
    if not r or r["kind"] == "base":
        return "Gains are measured from the base rollout's held-out loss."
    what = ("per frame the median loss of" if r["kind"] == "median"
            else f"the one that misses the held-out frames least ({r.get('which')}) of")
    return (f"Gains of physics and fill candidates are measured from {what} the base model's {r['predictions']} "
            f"predictions, its rollout and its realisations (held-out loss {r['heldout_loss']:.3f}); those of "
            "observation candidates (time and camera offsets), which re-draw the base rollout, from that rollout.")


def markdown(report: dict) -> str:
    """report.md: decision, base vs extended, the candidate ranking with the null, the split."""
    b, e = report["baseline"], report["extended"]
    lines = ["# Discrepancy report", "", f"Recordings: {', '.join(report['recordings'])} (camera {report['camera']})", "",
             f"**Decision: `{report['decision']}`**", "",
             "| held-out | loss (lower is better) | 95 % interval | IOU |", "|---|---|---|---|",
             f"| base ({_fmt(b['params'])}) | {b['heldout_loss']:.3f} | {_fmt(b['ci95_loss'])} | {b['heldout_iou']:.3f} |",
             f"| extended (`{e['name']}`) | {e['heldout_loss']:.3f} | {_fmt(e['ci95_loss'])} | {e['heldout_iou']:.3f} |", "",
             "## Candidates, ranked by held-out gain", "", _reference_line(report), "",
             "| # | candidate | fitted | gain | 95 % interval | IOU gain | null gains (fitted there) | threshold | declared |",
             "|---|---|---|---|---|---|---|---|---|"]
    for i, c in enumerate(report["candidates"], 1):
        g = c["heldout_gain"]
        params = ", ".join(f"{k}={v:.4g}" for k, v in c["params"].items())
        if c.get("tied"):
            params += f" (same loss from {c['tied'][0]:.4g} to {c['tied'][1]:.4g})"
        declared = ("yes" if c.get("declared") else "" if not c.get("not_declared")
                    else "no: within a frame" if c.get("sub_frame") else "no: recalibration")
        lines.append(f"| {i} | {c['name']} | {params} | {g['mean']:.3f} | {_fmt(g['ci95'])} | {c['heldout_iou_gain']:+.3f} | "
                     f"{_null_cell(c)} | {_fmt(c.get('null_threshold'))} | {declared} |")
    if report.get("learned"):
        g = report["learned"]["heldout_gain"]
        lines += ["", f"No candidate explains the residual: a minimum-norm learned correction a = W [v, 1] "
                      f"(ridge on the tracker's corrections) gains {g['mean']:.3f} {_fmt(g['ci95'])} held out."]
    lines += ["", "## Evidence in the base model's residuals", ""]
    for c in report["candidates"]:
        ev = {k: v for k, v in c["evidence"].items() if k != "tracker"}
        if ev:
            lines.append(f"- {c['name']}: " + ", ".join(f"{k} = {_fmt(v)}" for k, v in ev.items()))
    tr = report.get("tracker_corrections") or {}
    if tr:
        lines.append("- the warp-field tracker's corrections (as accelerations): "
                     + ", ".join(f"{k} = {_fmt(v)}" for k, v in tr.items()))
    s = report["split"]
    lines += ["", "## Split", "", f"By {s['by']}: {s['fit_frames']} fitting frames, {s['held_out_frames']} held-out frames "
              "(frames where neither the recording nor the model shows liquid are left out).", "",
              f"Null: {report['null'].get('level_runs', report['null']['runs'])} realisations of the fitted base model "
              "(the tracker's pose error redrawn, λ within the calibration's step); their base held-out loss "
              f"{_fmt(report['null']['base_heldout_loss'])} (the recording's: {b['heldout_loss']:.3f}; a residual is real above "
              f"{report['null']['residual_factor']} × the largest: {'yes' if report['null']['residual_real'] else 'no'}; "
              "this decides `unexplained` against `none` when nothing is declared). "
              f"A candidate is declared when its gain's interval is above 0 and its gain exceeds a bar from its null "
              f"gains: {report['null']['factor']} × the largest + {report['null']['margin']} when the residual is real; "
              "when it is not, " + (f"the largest (at least 0) + {report['null']['factor']} × their range + "
                                    f"{report['null']['margin']}" if report["null"].get("bar") == "spread" else
                                    f"{report['null']['factor']} × their largest magnitude + {report['null']['margin']}")
              + (" (the largest for gains measured from the best prediction)" if _ref_kind(report) == "best" else "")
              + f"; the best few are fitted on the first {report['null']['runs']} "
              "realisations in ranked order until one is declared"
              + (", a physics candidate's gain there measured from the base model's other predictions"
                 if _ref_kind(report) != "base" else "")
              + (". A viscosity or cohesion fitted within the calibration's own search range is a finer "
                 "calibration and is not declared" if not report.get("options", {}).get("recalibrations") else "")
              + (". A time offset shorter than one frame period of the camera is not declared"
                 if not report.get("options", {}).get("sub_frame_offsets") else "")
              + ".", "",
              "Time per stage (s): " + ", ".join(f"{k} {v}" for k, v in report["timing_s"].items()), ""]
    return "\n".join(lines)


def _plots(report: dict, out: Path, base_cells, ext_cells, obs_cells) -> list:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    files = []
    s = report["_series"]
    fig, ax = plt.subplots(figsize=(8, 3.2))
    for k, t in enumerate(s["t"]):
        t = np.asarray(t)
        ax.plot(t, s["base_iou"][k], color="tab:gray", label="base" if k == 0 else None)
        ax.plot(t, s["extended_iou"][k], color="tab:blue", label=f"extended ({report['extended']['name']})" if k == 0 else None)
        held = np.asarray(s["held"][k], bool)
        ax.scatter(t[held], np.zeros(held.sum()), marker="|", color="tab:orange", label="held out" if k == 0 else None)
    ax.set_xlabel("time, s")
    ax.set_ylabel("IOU")
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    files.append(out / "iou_over_time.png")
    fig.savefig(files[-1], dpi=110)
    plt.close(fig)

    wet = [(c.sum((1, 2)) >= MIN_CELLS) | (o.sum((1, 2)) >= MIN_CELLS) for c, o in zip(base_cells, obs_cells)]
    def mean_map(cells):
        return np.mean([c[w].mean(0) if w.any() else np.zeros(c.shape[1:]) for c, w in zip(cells, wet)], 0)
    obs, base, ext = mean_map(obs_cells), mean_map(base_cells), mean_map(ext_cells)
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.4))
    for ax, m, title in ((axes[0], obs - base, "observed − base"), (axes[1], obs - ext, "observed − extended")):
        lim = max(float(np.abs(obs - base).max()), 1e-6)
        im = ax.imshow(m, cmap="RdBu_r", vmin=-lim, vmax=lim)
        ax.set_title(f"{title} (share of frames)", fontsize=9)
        ax.axis("off")
    fig.colorbar(im, ax=axes, shrink=0.8, label="+: liquid the model misses")
    files.append(out / "residual_maps.png")
    fig.savefig(files[-1], dpi=110)
    plt.close(fig)

    cands = report["candidates"]
    fig, ax = plt.subplots(figsize=(7, 0.35 * len(cands) + 1.2))
    y = np.arange(len(cands))[::-1]
    g = np.array([c["heldout_gain"]["mean"] for c in cands])
    lo = np.array([c["heldout_gain"]["ci95"][0] for c in cands])
    hi = np.array([c["heldout_gain"]["ci95"][1] for c in cands])
    colors = ["tab:green" if c.get("declared") else "tab:gray" for c in cands]
    ax.barh(y, g, xerr=[g - lo, hi - g], color=colors, capsize=3)
    for yi, c in zip(y, cands):
        if "null_threshold" in c:
            ax.plot([c["null_threshold"]] * 2, [yi - 0.4, yi + 0.4], color="tab:red")
    ax.set_yticks(y, [c["name"] for c in cands])
    ax.axvline(0, color="k", lw=0.8)
    ax.set_xlabel("held-out gain (coarse loss); red: null threshold")
    fig.tight_layout()
    files.append(out / "candidates.png")
    fig.savefig(files[-1], dpi=110)
    plt.close(fig)
    return files


def write_report(report: dict, out, eps, base_cells, ext_cells, obs_cells) -> dict:
    """Write report.json, report.md, model.json and the PNGs into directory ``out``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    save_model(model_from_dict(report["model"]), out / "model.json")
    files = _plots(report, out, base_cells, ext_cells, obs_cells)
    doc = {k: v for k, v in report.items() if k != "_series"}
    doc["series"] = report["_series"]
    doc["files"] = [str(p.name) for p in files] + ["report.md", "model.json"]
    (out / "report.json").write_text(json.dumps(doc, indent=1, default=float) + "\n")
    (out / "report.md").write_text(markdown(report))
    return doc
