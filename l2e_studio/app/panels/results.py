"""The result of the last run: its verdict in words, the score at seed and at result (pooled and
per scene), accept it as the new seed or discard it, and save the result file with a
before/after image."""

from __future__ import annotations

from typing import Sequence

import viser

from ..context import Workbench
from ...errors import InputError
from ..handback import Answer, ResultScores
from ..heldout import HeldOutScore
from ..pose import describe
from ..text import change, score_label, score_num
from ..state import Snapshot

NO_RESULT = "No result yet."


class ResultPanel:
    def __init__(self, app: Workbench) -> None:
        self.app = app
        gui = app.server.gui
        self.summary = gui.add_markdown(NO_RESULT)
        self.accept = gui.add_button("Accept as seed", color="green", icon=viser.Icon.CHECK, disabled=True,
                                     hint="Make the result the current extrinsic (the next run starts there)")
        self.discard = gui.add_button("Discard", icon=viser.Icon.TRASH, disabled=True)
        self.save = gui.add_button("Save result", icon=viser.Icon.DEVICE_FLOPPY, disabled=True,
                                   hint="Write a result file and a before/after PNG into the results folder")
        self.saved = gui.add_markdown("")
        self.folder = gui.add_text("Results folder", str(app.out_dir),
                                   hint="Where result files and seeds are written (created on the first save)")
        self.folder_note = gui.add_markdown("", visible=False)
        self.folder.on_update(self._on_folder)
        self.table = gui.add_markdown("")
        self.accept.on_click(self._accept)
        self.discard.on_click(lambda event: app.discard_result())
        self.save.on_click(self._on_save)
        self._saved_for: object | None = None  # the result the "Saved ..." line is about

    def _on_folder(self, event) -> None:
        try:
            note = self.app.set_out_dir(self.folder.value)
        except ValueError as exc:
            note = f"{exc}; still writing to {self.app.out_dir}"
        self.folder_note.content = f"⚠ {note}" if note else ""
        self.folder_note.visible = bool(note)

    def _accept(self, event) -> None:
        self.app.accept_result()
        self.app.notify(event.client, "Result accepted", "The sliders now show the result; Start again to refine.",
                        color="green")

    def _on_save(self, event) -> None:
        result = self.app.state.snapshot().result
        try:
            path, png = self.app.save_result()
        except (InputError, OSError, RuntimeError) as exc:
            self.app.notify(event.client, "Result not saved", str(exc), color="red")
            return
        body = f"{path}" + (f" and {png}" if png else "")
        self._saved_for = result
        self.saved.content = f"Saved `{path}`" + (f"  \nand `{png}`" if png else "")
        self.app.notify(event.client, "Result saved", body, color="green")
        if event.client is not None:  # on this computer too (over SSH the server's folder is elsewhere)
            event.client.send_file_download(path.name, path.read_bytes())

    def show(self, snap: Snapshot, held_out: Sequence[HeldOutScore] = (), scores: ResultScores | None = None) -> None:
        r = snap.result
        has = r is not None
        self.accept.disabled = not has
        self.discard.disabled = not has
        self.save.disabled = not has
        if r is not self._saved_for:  # never a "Saved ..." line about another result
            self.saved.content = ""
            self._saved_for = None
        if not has:
            self.summary.content = NO_RESULT
            self.table.content = ""
            return
        cancelled = bool(r.cancelled)
        v = snap.verdict
        # Only a result the verdict trusts gets the green "go": a cancelled run's point is not a
        # converged result, and an untrusted one is accepted only on the user's own judgement.
        self.accept.color, self.accept.label = accept_style(cancelled, v)
        state = ("■ **Run cancelled**: the best point so far, not a converged result" if cancelled
                 else "■ **Run finished, judging cancelled**" if snap.judging_cancelled
                 else "✓ **Run finished**")
        label = scores.label if scores is not None else score_label(r.objective)
        if scores is None:  # not scored on the readout's scale: the run's own numbers
            scores = ResultScores(Answer("the run's seed", r.seed, r.score_seed),
                                  Answer("the optimiser's own answer", r.extrinsic, r.score_result),
                                  *(2 * [Answer("the optimiser's answer", r.extrinsic, r.score_result)]),
                                  per_scene_accepted=None)
        seed = scores.seed.score

        def line(head: str, a: Answer, what: bool = True) -> str:
            deg, m = r.seed.error_to(a.extrinsic)
            return (f"**{head}**: " + (f"{a.what} · " if what else "")
                    + f"**{label} {score_num(a.score)}** ({change(a.score, seed)} vs the "
                    f"run's seed {score_num(seed)}) · moved {deg:.3f}° / {100 * m:.2f} cm from the seed")

        lines = [f"{state} · {'checkerboard' if r.method == 'target' else r.settings.method} · {r.evaluations} evaluations · {r.seconds:.1f} s · "
                 f"{len(r.scene_names)} scenes" + (f", {len(held_out)} held out" if held_out else ""),
                 verdict_text(v) if v is not None else not_judged_text(cancelled or snap.judging_cancelled)]
        if scores.accepted.extrinsic is scores.file.extrinsic:
            lines.append(line("Handed back (Accept, Save, exports)", scores.accepted))
        else:  # not trusted: the file keeps the seed, Accept is the user's call
            lines.append(line("Saved file and exports hand back", scores.file))
            lines.append(line("Accept sets", scores.accepted))
        if not scores.same:
            lines.append(line("The optimiser's own answer (not handed back)", scores.optimiser, what=False))
        lines.append(f"After Accept: {describe(scores.accepted.extrinsic, self.app.state.reference)}")
        self.summary.content = "  \n".join(lines)
        self.table.content = result_table(r, held_out, scores.per_scene_accepted, self.app.state.scene_names,
                                          scores.per_scene_seed, scores.label or None)


def not_judged_text(cancelled: bool) -> str:
    """The verdict line of a result without a verdict (markdown)."""
    why = "the run or its judging was cancelled" if cancelled else "judging failed (see the log)"
    return f"◌ **Verdict: not judged**: {why}; nothing vouches for this result"


VERDICT_MARKS = {"trusted": "✓", "trusted-rotation": "◐", "not-trusted": "✗"}


def verdict_text(verdict) -> str:
    """The verdict in words, with why (markdown)."""
    head = f"{VERDICT_MARKS[verdict.status]} **Verdict: {verdict.summary()}**"
    pinned, lever = verdict.pinned(), verdict.lever_line()
    return (head + "".join(f"  \n· {r}" for r in verdict.reasons)
            + (f"  \n= {pinned}" if pinned else "")
            + "".join(f"  \n→ {a}" for a in ([lever] if lever else []) + verdict.advice()))


def accept_style(cancelled: bool, verdict) -> tuple[str, str]:
    """(colour, label) of the Accept button for a run's result and its verdict."""
    if cancelled:
        return "yellow", "Accept best-so-far as seed (not judged)"
    if verdict is None:
        return "yellow", "Accept as seed (not judged)"
    if verdict.seed_stands:
        return "green", "Keep the seed (confirmed)"
    if verdict.settled:
        return "green", f"Accept (seed's {' and '.join(verdict.from_seed())} kept)"
    if verdict.status == "trusted":
        return "green", "Accept as seed"
    if verdict.status == "trusted-rotation" and verdict.seed_axes != "xyz":
        return "green", f"Accept (seed's translation kept along {', '.join(verdict.seed_axes)})"
    if verdict.status == "trusted-rotation":
        return "green", "Accept rotation (seed's translation kept)"
    return "red", "Accept anyway (not trusted)"


def result_table(result, held_out: Sequence[HeldOutScore] = (), accepted=None, names: Sequence[str] = (),
                 seed=None, label: str | None = None) -> str:
    """Markdown: one row per optimised scene, then the held-out ones marked as such. The result
    column is what Accept sets (``accepted``: every scene's score there, in ``names`` order),
    else the optimiser's answer; ``seed`` (same order) and ``label``: the readout's numbers at the
    run's seed and its score's name, so that both columns are on one scale (a checkerboard run's
    own numbers are its board planes, not the readout's score)."""
    label = label or score_label(result.objective)
    index = {n: i for i, n in enumerate(names)}
    head = "after Accept" if accepted is not None else "result"
    rows = [f"| scene | {label} seed | {label} {head} | change |", "|:--|--:|--:|--:|"]
    for name, a, b in zip(result.scene_names, result.score_seed_per_scene, result.score_result_per_scene):
        if accepted is not None and name in index:
            b = accepted[index[name]]
        if seed is not None and name in index:
            a = seed[index[name]]
        rows.append(f"| {name} | {score_num(a)} | {score_num(b)} | {change(b, a)} |")
    for h in held_out:
        rows.append(f"| {h.name} (held out) | {score_num(h.score_seed)} | {score_num(h.score_result)} | "
                    f"{change(h.score_result, h.score_seed)} |")
    if held_out:
        rows += ["", f"Held-out scenes were not optimised over: their {label} (at the optimiser's answer) checks "
                     "the result on unseen data."]
    return "\n".join(rows)
