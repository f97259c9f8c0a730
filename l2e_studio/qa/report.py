"""``l2e-studio report``: one self-contained HTML file a reviewer opens offline.

Every figure is embedded as a base64 data URI (plots as PNG, overlays and crops as JPEG, quality 80-85, to
keep 40 full-size scenes in a file of reasonable size); no script, font or style is fetched.
The numbers behind the page are embedded too, as JSON in ``<script type="application/json"
id="l2e-qa-data">``.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import html
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from .. import __version__
from ..calibrate import CalibrationSettings, stack_scenes
from ..export import EXPORT_FORMATS, export_status, export_text
from ..geometry import Extrinsic
from ..score_maps import CLIP
from ..scenes import SceneSet
from . import AXES, UNITS, figures, guardrails
from .heldout import Candidate, ScoreTable, score
from .landscape import Sweep1D, Sweep2D, sweep2d, sweeps
from .studies import correction
from .uncertainty import Uncertainty, curvature, from_half_samples


@dataclass
class ReportInputs:
    scene_set: SceneSet
    result: dict  # the parsed result file
    result_path: Path
    settings: CalibrationSettings
    seed: Extrinsic
    extrinsic: Extrinsic
    candidates: list[Candidate] = field(default_factory=list)  # besides seed and result
    groups: dict[str, list[str]] | None = None
    held_out: np.ndarray | None = None
    truth: Extrinsic | None = None
    studies: list[tuple[Path, dict]] = field(default_factory=list)
    pair: tuple[str, str] = ("z", "rx")
    steps: int = 21
    span_m: float = 0.05
    span_deg: float = 2.0
    wanted_mm: float | None = None
    wanted_deg: float | None = None
    extra_files: list[Path] = field(default_factory=list)


def settings_from_result(result: dict) -> CalibrationSettings:
    """The score climb's settings a result file records; a checkerboard result (``method:
    target``) records its own solver, so the report scores it with the default climb settings."""
    if result.get("method") == "target":
        return CalibrationSettings()
    b = result.get("bounds") or {}
    o = result.get("optimiser") or {}
    kw = {}
    if "translation_m" in b:
        kw["translation_bound"] = float(b["translation_m"])
    if "rotation_deg" in b:
        kw["rotation_bound_deg"] = float(b["rotation_deg"])
    if o.get("sigma_px") is not None:
        kw["sigma"] = float(o["sigma_px"])
    if o.get("method"):
        kw["method"] = str(o["method"])
    if o.get("rotation_only") is not None:
        kw["rotation_only"] = bool(o["rotation_only"])
    return CalibrationSettings(**kw)


def sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def input_files(scene_set: SceneSet) -> list[Path]:
    root = Path(scene_set.root)
    files = [p for p in sorted(root.rglob("*")) if p.is_file() and ".l2e_cache" not in p.parts and "results" not in p.parts]
    return files


def build(inp: ReportInputs, on_progress: Callable[[str], None] | None = None) -> tuple[str, dict]:
    """(the HTML page, the numbers in it)."""
    say = on_progress or (lambda _msg: None)
    ss = inp.scene_set
    say("stacking scenes")
    stack = stack_scenes(ss.scenes, ss.camera, inp.seed, inp.settings)
    names = list(stack.names)
    held = inp.held_out
    if held is None:
        used = inp.result.get("scenes")
        held = np.array([n not in used for n in names], bool) if used else np.zeros(len(names), bool)
    cands = [Candidate("seed", inp.seed, "result file: seed"), Candidate("result", inp.extrinsic, str(inp.result_path))]
    if inp.truth is not None:
        cands.append(Candidate("truth", inp.truth, "truth.yaml"))
    cands += [c for c in inp.candidates if c.name not in {"seed", "result", "truth"}]
    say("scoring candidates")
    table = score(stack, cands, inp.groups, held)
    say("landscape")
    sw = sweeps(stack, inp.extrinsic, inp.span_m, inp.span_deg, inp.steps)
    a, b = inp.pair
    span = lambda ax: inp.span_m if ax in AXES[:3] else inp.span_deg  # noqa: E731
    sw2 = sweep2d(stack, inp.extrinsic, a, b, span(a), span(b), n=max(5, inp.steps // 2 + 1))
    say("uncertainty")
    unc: list[Uncertainty] = []
    try:
        unc.append(curvature(stack, inp.extrinsic, inp.settings.rotation_only))
    except Exception as exc:  # too few scenes, singular Hessian: say so in the report
        unc_error = f"curvature estimate unavailable: {exc}"
    else:
        unc_error = ""
    for path, st in inp.studies:
        if st.get("summary", {}).get("kind") == "bootstrap":
            unc.append(from_half_samples(np.array([r["result"] for r in st["runs"]])))
    ri = [c.name for c in cands].index("result")
    warns = (guardrails.held_out_below_seed(table) + guardrails.on_bound(inp.extrinsic, inp.seed, inp.settings)
             + guardrails.few_points(names, table.points_in_image[ri])
             + guardrails.few_scenes(len(names) - int(held.sum()), unc[0].std if unc else None, inp.wanted_mm, inp.wanted_deg)
             + guardrails.few_places(stack.places[~np.asarray(held, bool)])
             + guardrails.flat_landscape(sw, score_name(stack.objective_name))
             + guardrails.held_out_used([n for n, h in zip(names, held) if h], inp.result.get("scenes")))
    true_err = correction(inp.truth, inp.extrinsic) if inp.truth is not None else None
    notes = guardrail_notes(warns, inp.result.get("verdict"))

    data = {
        "l2e_studio_version": __version__,
        "created": _dt.datetime.now().astimezone().isoformat(timespec="seconds"),
        "result_file": str(inp.result_path),
        "settings": {"translation_bound_m": inp.settings.translation_bound, "rotation_bound_deg": inp.settings.rotation_bound_deg,
                     "sigma_px": inp.settings.sigma, "method": inp.settings.method, "rotation_only": inp.settings.rotation_only},
        "verdict": inp.result.get("verdict"),
        "quality": inp.result.get("quality"),
        "guardrails": [w.to_dict() for w in warns],
        "scores": table.to_dict(),
        "landscape": [s.to_dict() for s in sw] + [sw2.to_dict()],
        "uncertainty": [u.to_dict() for u in unc],
        "true_error": dict(zip(AXES, np.round(true_err, 6).tolist())) if true_err is not None else None,
        "studies": [{"file": str(p), "summary": st.get("summary")} for p, st in inp.studies],
    }

    say("checksums")
    files = [inp.result_path, *input_files(ss), *[p for p, _ in inp.studies], *inp.extra_files]
    sums = [(str(p), p.stat().st_size, sha256(p)) for p in dict.fromkeys(files) if Path(p).is_file()]
    data["inputs"] = [{"file": f, "bytes": n, "sha256": h} for f, n, h in sums]

    say("figures")
    page = _page(inp, ss, table, sw, sw2, unc, unc_error, warns, notes, true_err, data, say, stack.objective_name)
    return page, data


# --- HTML ------------------------------------------------------------------------------------------

CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;margin:24px auto;max-width:1500px;color:#222;padding:0 16px}
h1{margin-bottom:4px} h2{border-bottom:2px solid #ddd;padding-bottom:4px;margin-top:36px}
table{border-collapse:collapse;margin:8px 0;font-size:13px} td,th{border:1px solid #ccc;padding:3px 8px;text-align:right}
th{background:#f3f3f3} td:first-child,th:first-child{text-align:left}
pre{background:#f7f7f7;border:1px solid #ddd;padding:8px;overflow-x:auto;font-size:12px}
.warn{background:#fff4e5;border-left:4px solid #f0a030;padding:6px 10px;margin:4px 0}
.ok{background:#eaf7ea;border-left:4px solid #3a3;padding:6px 10px}
.bad{background:#fdecea;border-left:4px solid #d33;padding:6px 10px}
figure{margin:8px 0} figcaption{font-size:12px;color:#555} img{max-width:100%;height:auto;border:1px solid #ccc}
.pair{display:flex;gap:8px;flex-wrap:wrap} .pair figure{flex:1 1 45%}
.held{color:#a05000;font-weight:600} .small{font-size:12px;color:#555}
table.checks td{text-align:left}
"""


def _e(x) -> str:
    return html.escape(str(x))


def _tbl(head: Sequence[str], rows: Sequence[Sequence], cls: str = "") -> str:
    h = "".join(f"<th>{_e(c)}</th>" for c in head)
    body = "".join("<tr>" + "".join(f"<td>{c if isinstance(c, _Raw) else _e(c)}</td>" for c in r) + "</tr>" for r in rows)
    return f'<table class="{cls}"><thead><tr>{h}</tr></thead><tbody>{body}</tbody></table>'


class _Raw(str):
    pass


#: How each objective's score is named in the report (the landscape is the score the optimiser climbed).
SCORE_NAMES = {"mi": "MI (nats)", "edges": "edge score"}
#: How each map kind is named in captions.
MAP_NAMES = {"events": "event map", "image": "camera image"}
VERDICT_CLASS = {"trusted": "ok", "trusted-rotation": "warn", "not-trusted": "bad"}
VERDICT_HEADLINES = {
    "trusted": "TRUSTED: the result passed every check",
    "trusted-rotation": "ROTATION TRUSTED, translation not: the seed's translation is handed back",
    "not-trusted": "NOT TRUSTED",
    "not judged": "NOT JUDGED: nothing checked this result",
    "no verdict": "NO VERDICT",
}
SEED_CONFIRMED = "SEED CONFIRMED: the result lies within its own spread of the seed, which is handed back"


def score_name(objective: str) -> str:
    return SCORE_NAMES.get(objective, objective)


def guardrail_notes(warns, verdict) -> list[str]:
    """Where a guardrail and a verdict check seem to disagree, what each measures (one line each)."""
    checks = (verdict or {}).get("checks") or {} if isinstance(verdict, dict) else {}
    single = checks.get("a single peak")
    out = []
    if any(w.code == "ambiguous" for w in warns) and isinstance(single, dict) and single.get("passed"):
        out.append("The landscape guardrail and the verdict's 'a single peak' check measure different things: the "
                   "guardrail reads a 1-D sweep through the result along one axis (a side bump within the sweep's "
                   "span, height above the sweep's minimum), the check compares where the global search's starts "
                   "ended (2 deg or more apart, 90 % of the score or more). A side bump the search never ended on "
                   "passes the check; judge the bump by its position and the overlays.")
    return out


def verdict_html(v) -> str:
    """The verdict as a headline in words, its reasons, and its checks as a table (no raw dump)."""
    status, lines = export_status({"verdict": v} if isinstance(v, dict) else {})
    head = VERDICT_HEADLINES.get(status, status.upper())
    if isinstance(v, dict) and v.get("seed_stands") is True:
        head = SEED_CONFIRMED  # trusted, and every part of the result within its spread of the seed
    out = [f"<div class='{VERDICT_CLASS.get(status, 'warn')}'><b>{_e(head)}</b>"
           + (f"<br>{_e(v['summary'])}" if isinstance(v, dict) and v.get("summary") else "") + "</div>"]
    out += [f"<p>{_e(line)}</p>" for line in lines[1:]]
    if not isinstance(v, dict):
        return "\n".join(out + ["<p class='small'>The result file holds no <code>verdict:</code> section.</p>"])
    reasons = v.get("reasons") or []
    if reasons:
        out.append("<p>Why:</p><ul>" + "".join(f"<li>{_e(r if not isinstance(r, dict) else json.dumps(r))}</li>"
                                                for r in reasons) + "</ul>")
    checks = v.get("checks") or {}
    if checks:
        out.append(_tbl(["check", "", "what was measured"],
                        [[name, "passed" if c.get("passed") else "FAILED", c.get("detail", "")]
                         for name, c in checks.items() if isinstance(c, dict)], cls="checks"))
    if isinstance(v.get("translation_pinned"), str):
        out.append(f"<p>{_e(v['translation_pinned'])}</p>")
    lever = v.get("rotation_per_cm_of_seed_translation")
    if isinstance(lever, dict) and isinstance(lever.get("note"), str):
        out.append(f"<p>{_e(lever['note'][:1].upper() + lever['note'][1:])}.</p>")
    rotation = v.get("rotation_advice")
    if isinstance(rotation, list) and rotation:
        out.append("<h3>Rotation: what to record or do</h3><ul>" + "".join(f"<li>{_e(a)}</li>" for a in rotation) + "</ul>")
    axes = v.get("translation_axes")
    advice = [a["advice"] for a in axes.values() if isinstance(a, dict) and a.get("advice")] if isinstance(axes, dict) else []
    if advice:
        out.append("<h3>Translation: what to record</h3><ul>" + "".join(f"<li>{_e(a)}</li>" for a in advice) + "</ul>")
    if v.get("seconds") is not None:
        out.append(f"<p class='small'>judged in {_e(v['seconds'])} s</p>")
    return "\n".join(out)


def _fmt(v, nd=4) -> str:
    return "-" if v is None or (isinstance(v, float) and not np.isfinite(v)) else f"{v:.{nd}f}"


def _page(inp, ss, table: ScoreTable, sw: list[Sweep1D], sw2: Sweep2D, unc, unc_error, warns, notes, true_err, data, say,
          objective: str = "mi") -> str:
    parts: list[str] = []
    add = parts.append
    add(f"<h1>L2E Studio calibration report</h1><p class='small'>{_e(data['created'])} - l2e-studio "
        f"{_e(__version__)} - result <code>{_e(inp.result_path)}</code> - scenes <code>{_e(ss.root)}</code></p>")

    # verdict
    add("<h2 id='verdict'>Verdict</h2>")
    add(verdict_html(inp.result.get("verdict")))
    add("<h3>Guardrails</h3>")
    add("".join(f"<div class='warn'><b>{_e(w.code)}</b>: {_e(w.message)}</div>" for w in warns) or "<div class='ok'>no warnings</div>")
    add("".join(f"<p class='small'>{_e(n)}</p>" for n in notes))
    if inp.result.get("quality"):
        add(f"<h3>Quality check in the result file</h3><pre>{_e(json.dumps(inp.result['quality'], indent=2))}</pre>")

    # result and exports
    add("<h2 id='result'>Result, in every export form</h2>")
    ext = inp.extrinsic
    add("<p class='small'>The result as a correction of the seed, in the camera frame (rx, ry, rz: rotations "
        "about the camera's x, y, z axes; absolute roll/pitch/yaw of a lidar-to-camera rotation sit at gimbal lock, "
        "where a small correction reads as a large change).</p>")

    def row(name: str, e: Extrinsic) -> list:
        corr = correction(inp.seed, e)
        deg, m = inp.seed.error_to(e)
        return [name, *[f"{v:.5f}" for v in e.translation], *[f"{v:+.2f}" for v in corr[:3]],
                *[f"{v:+.4f}" for v in corr[3:]], f"{deg:.4f}", f"{1000 * m:.2f}"]

    rows = [row("seed", inp.seed), row("result (handed back)", ext)]
    own = (inp.result.get("optimiser_result") or {}).get("T_cam_lidar")
    if own is not None and not np.allclose(own, ext.matrix, atol=1e-9):
        rows.append(row("the optimiser's own answer (not handed back)", Extrinsic.from_matrix(np.asarray(own, float))))
    add(_tbl(["", "x (m)", "y (m)", "z (m)", "dx (mm)", "dy (mm)", "dz (mm)", "drx (deg)", "dry (deg)", "drz (deg)",
              "rotation (deg)", "translation (mm)"], rows))
    doc = inp.result if "T_cam_lidar" in inp.result else None
    for fmt in EXPORT_FORMATS:
        if fmt in ("yaml", "json"):
            continue
        add(f"<h3>{_e(fmt)}</h3><pre>{_e(export_text(ext, fmt, result=doc))}</pre>")
    add(f"<h3>yaml (transform)</h3><pre>{_e(export_text(ext, 'yaml'))}</pre>")

    # scores
    add("<h2 id='scores'>Per-scene and held-out scores (paper's MI, nats; Table III)</h2>")
    if objective != "mi":
        add(f"<p class='small'>These tables use the paper's MI whatever the optimiser climbed (here the "
            f"{_e(score_name(objective))}); the landscape below is the {_e(score_name(objective))}.</p>")
    names = [c.name for c in table.candidates]
    rows = []
    for j, s in enumerate(table.scenes):
        best = int(np.nanargmax(table.per_scene[:, j]))
        rows.append([_Raw(f"<span class='held'>{_e(s)} (held out)</span>") if table.held_out[j] else s,
                     *[_Raw(f"<b>{_fmt(table.per_scene[i, j])}</b>") if i == best else _fmt(table.per_scene[i, j])
                       for i in range(len(names))],
                     int(table.points_in_image[names.index("result"), j])])
    add(_tbl(["scene", *names, "points in image (result)"], rows))
    add("<h3>Pooled by group</h3>")
    add(_tbl(["group", "scenes", *names], [[g, int(m.sum()), *[_fmt(table.pooled[g][i]) for i in range(len(names))]]
                                           for g, m in table.groups.items()]))
    add("<h3>Differences between candidates</h3>")
    add(_tbl(["a", "b", "rotation (deg)", "translation (mm)", "dx dy dz (mm)", "drx dry drz (deg)"],
             [[a, b, f"{d['rotation_deg']:.4f}", f"{d['translation_mm']:.2f}", " ".join(f"{v:+.2f}" for v in d["per_axis_mm"]),
               " ".join(f"{v:+.4f}" for v in d["per_axis_deg"])] for (a, b), d in table.differences.items()]))

    target = inp.result.get("target")
    if isinstance(target, dict) and target.get("frames"):
        add(_target_section(target))

    # uncertainty
    add("<h2 id='uncertainty'>Uncertainty</h2>")
    urows = [[u.method, *[f"{v:.4g}" for v in u.std]] for u in unc]
    for p, st in inp.studies:
        summ = st.get("summary") or {}
        for m, s in (summ.get("methods") or {}).items():
            if summ.get("kind") == "repeatability":
                urows.append([f"repeatability spread ({m}, {s['runs']} runs, {Path(p).name})",
                              *[_fmt(s["std"][a], 4) for a in AXES]])
    if true_err is not None:
        urows.append(["true error of the result (truth known)", *[f"{v:+.4g}" for v in true_err]])
    add(_tbl(["estimate", *[f"{a} ({u})" for a, u in zip(AXES, UNITS)]], urows) if urows else "")
    if unc_error:
        add(f"<div class='warn'>{_e(unc_error)}</div>")

    # landscapes
    say("landscape figures")
    add("<h2 id='landscape'>Landscape around the result</h2>")
    label = score_name(objective)
    add(f"<figure><img alt='1-D score sweeps' src='{figures.landscape_figure(sw, label)}'><figcaption>{_e(label)} "
        f"(all scenes pooled, the score the optimiser climbed) along each axis through the result (dashed).</figcaption></figure>")
    add(_tbl(["axis", "peak offset", "half width", "second peak / main"],
             [[s.axis, f"{s.peak_offset:+.4g}", f"{s.half_width():.4g}", f"{s.secondary_ratio():.2f}"] for s in sw]))
    add(f"<figure><img alt='2-D score sweep' src='{figures.landscape2d_figure(sw2, label)}' style='max-width:600px'>"
        f"<figcaption>{_e(label)} over {_e(sw2.axes[0])} x {_e(sw2.axes[1])} around the result (+).</figcaption></figure>")

    # studies
    add("<h2 id='studies'>Repeatability and scene-count studies</h2>")
    if not inp.studies:
        add("<p class='small'>No study given (<code>l2e-studio study ... --out study.json</code>, then "
            "<code>report --study study.json</code>).</p>")
    for p, st in inp.studies:
        summ = st.get("summary") or {}
        add(f"<h3>{_e(summ.get('kind', 'study'))}: {_e(Path(p).name)}</h3><p class='small'>{summ.get('runs')} runs, "
            f"noise +-{_e((summ.get('noise') or {}).get('translation_m'))} m / +-{_e((summ.get('noise') or {}).get('rotation_deg'))} deg "
            f"per axis, parameters relative to the {_e(summ.get('reference'))}; {_e(summ.get('executor'))}, wall "
            f"{_e(summ.get('wall_seconds'))} s{' (cancelled)' if summ.get('cancelled') else ''}</p>")
        mrows = []
        for m, s in (summ.get("methods") or {}).items():
            mrows.append([m, s["runs"], *[f"{_fmt(s['mean'][a], 3)} +- {_fmt(s['std'][a], 3)}" for a in AXES],
                          f"{s['seconds_mean']:.2f} +- {_fmt(s['seconds_std'], 2)}", s["evaluations_mean"]])
        add(_tbl(["optimiser", "runs", *[f"{a} ({u})" for a, u in zip(AXES, UNITS)], "run time (s)", "evaluations"], mrows))
        runs = st.get("runs") or []
        if runs and summ.get("kind") in ("repeatability", "bootstrap"):
            add(f"<figure><img alt='results against seeds' src='{figures.scatter_figure(np.array([r['seed'] for r in runs], float), np.array([r['result'] for r in runs], float), [r['method'] for r in runs])}'>"
                "<figcaption>Each run's result against its seed, per parameter.</figcaption></figure>")
        counts = summ.get("scene_counts") or {}
        if counts:
            ks = sorted(int(k) for k in counts)
            stds = np.array([[counts.get(k, counts.get(str(k)))["std"][a] or np.nan for a in AXES] for k in ks], float)
            add(_tbl(["scenes", "runs", *[f"std {a} ({u})" for a, u in zip(AXES, UNITS)]],
                     [[k, counts.get(k, counts.get(str(k)))["runs"], *[_fmt(v, 4) for v in stds[i]]] for i, k in enumerate(ks)]))
            add(f"<figure><img alt='spread against scene count' src='{figures.scene_count_figure(ks, stds)}'>"
                "<figcaption>Spread of the result against the number of scenes used.</figcaption></figure>")

    # overlays
    kinds = sorted({sc.map_kind for sc in ss.scenes})
    shown = " or ".join(f"coloured by {'intensity' if k == 'events' else 'depth'} over the {MAP_NAMES.get(k, k)}" for k in kinds)
    add("<h2 id='overlays'>Before / after, every scene</h2><p class='small'>Lidar points "
        f"{_e(shown)}: seed (left) and result (right), full resolution, then an enlarged crop of the region "
        "with most structure.</p>")
    cam = ss.camera
    for k, sc in enumerate(ss.scenes):
        say(f"overlay {k + 1}/{len(ss.scenes)}")
        clip = CLIP.get(sc.map_kind, 127.0)
        before = figures.overlay(sc.event_map, sc.points, sc.intensity, inp.seed, cam, clip, map_kind=sc.map_kind)
        after = figures.overlay(sc.event_map, sc.points, sc.intensity, ext, cam, clip, map_kind=sc.map_kind)
        box = figures.crop_box(sc.event_map)
        zoom = figures.crop_factor(cam, box)
        crops = [figures.overlay(sc.event_map, sc.points, sc.intensity, e, cam, clip, map_kind=sc.map_kind, box=box,
                                 factor=zoom) for e in (inp.seed, ext)]
        f = figures.display_factor(cam)
        j = table.scenes.index(sc.name) if sc.name in table.scenes else -1
        mi = (f" - paper's MI seed {_fmt(table.per_scene[0, j])}, result {_fmt(table.per_scene[1, j])}"
              + (" (held out)" if table.held_out[j] else "")) if j >= 0 else ""
        kind = MAP_NAMES.get(sc.map_kind, sc.map_kind)
        add(f"<h3>{_e(sc.name)} ({_e(kind)}){_e(mi)}</h3><div class='pair'>"
            f"<figure><img alt='{_e(sc.name)} seed' src='{figures.data_uri_jpeg(before)}'><figcaption>seed, full resolution{_e(f' (drawn at {f}x)' if f > 1 else '')}</figcaption></figure>"
            f"<figure><img alt='{_e(sc.name)} result' src='{figures.data_uri_jpeg(after)}'><figcaption>result, full resolution{_e(f' (drawn at {f}x)' if f > 1 else '')}</figcaption></figure>"
            f"<figure><img alt='{_e(sc.name)} seed crop' src='{figures.data_uri_jpeg(crops[0], 85)}'><figcaption>seed, crop x{box[0]} y{box[1]} {box[2]}x{box[3]} px (map pixels), enlarged {zoom}x, points at the same size</figcaption></figure>"
            f"<figure><img alt='{_e(sc.name)} result crop' src='{figures.data_uri_jpeg(crops[1], 85)}'><figcaption>result, same crop</figcaption></figure>"
            "</div>")

    # settings and checksums
    add("<h2 id='inputs'>Settings and input files</h2>")
    add(f"<pre>{_e(json.dumps(data['settings'], indent=2))}</pre>")
    add(f"<p class='small'>camera: {_e(cam.model)} {cam.width}x{cam.height}, K = {_e(np.round(cam.K, 4).tolist())}, "
        f"D = {_e(np.round(cam.D, 6).tolist())}</p>")
    add(_tbl(["file", "bytes", "sha256"], [[f["file"], f["bytes"], _Raw(f"<code>{f['sha256']}</code>")] for f in data["inputs"]]))

    blob = json.dumps(data, default=_json_default).replace("</", "<\\/")
    return ("<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'><title>L2E calibration report</title>"
            f"<style>{CSS}</style></head><body>" + "\n".join(parts)
            + f"<script type='application/json' id='l2e-qa-data'>{blob}</script></body></html>\n")


def _mm(v, nd=1) -> str:
    return "-" if v is None else f"{1000.0 * float(v):.{nd}f}"


def _target_section(target: dict) -> str:
    """The checkerboard result's frames: detection, lidar board, residuals, used or left out and why,
    how far leaving each out moves the result; the residual plot; the per-axis uncertainty."""
    frames = target["frames"]
    rows = []
    for f in frames:
        name = f.get("name")
        cell = _Raw(f"<span class='held'>{_e(name)} (left out)</span>") if not f.get("used") else name
        moved = ("-" if f.get("leave_out_moves_m") is None else
                 f"{_mm(f['leave_out_moves_m'], 2)} mm / {_fmt(f.get('leave_out_moves_deg'), 4)} deg")
        rows.append([cell, "yes" if f.get("detected") else "no", f.get("detector") or "-",
                     _fmt(f.get("reprojection_px"), 2), f.get("lidar_points", 0), f.get("edge_points", 0),
                     _mm(f.get("plane_rms_m")), _mm(f.get("plane_mean_m")), _mm(f.get("edge_rms_m")), moved,
                     f.get("reason") or ""])
    used = sum(bool(f.get("used")) for f in frames)
    detected = sum(bool(f.get("detected")) for f in frames)
    board = target.get("board") or {}
    head = (f"<p class='small'>Board {_e(board.get('squares'))} squares of {_e(board.get('square_m'))} m, "
            f"outer {_e(board.get('size_m'))} m. Board found in {detected} of {len(frames)} images; "
            f"{used} frames used. Plane RMS over the used frames {_mm(target.get('plane_rms_m'))} mm, edge RMS "
            f"{_mm(target.get('edge_rms_m'))} mm.</p>")
    obs = target.get("observability") or {}
    if obs:
        cls = "ok" if obs.get("observed") else "warn"
        words = obs.get("advice") or (f"every axis pinned (board normals spread {obs.get('normal_spread')} along "
                                      f"their weakest direction {obs.get('weakest_direction')})")
        add_obs = f"<div class='{cls}'>board orientations: {_e(words)}</div>"
    else:
        add_obs = ""
    sigma = target.get("sigma") or {}
    sig = (_tbl(["", "x (mm)", "y (mm)", "z (mm)", "rx (deg)", "ry (deg)", "rz (deg)"],
                [["per-axis standard deviation (camera frame)", *[_mm(sigma.get(k), 2) for k in ("x_m", "y_m", "z_m")],
                  *[_fmt(sigma.get(k), 4) for k in ("rx_deg", "ry_deg", "rz_deg")]]]) if sigma else "")
    table = _tbl(["frame", "board", "detector", "reprojection (px)", "lidar points", "edge points", "plane RMS (mm)",
                  "plane mean (mm)", "edge RMS (mm)", "left out, the result moves", "note"], rows)
    fig = (f"<figure><img alt='checkerboard residuals per frame' src='{figures.target_residuals_figure(frames)}'>"
           "<figcaption>Per frame: the lidar board points' RMS distance to the camera's board plane and the edge "
           "points' distance to the board's outline (frames left out hatched grey), and the corners' "
           "reprojection error.</figcaption></figure>")
    return "<h2 id='target'>Checkerboard frames</h2>" + head + add_obs + table + fig + sig


def _json_default(o):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    return str(o)
