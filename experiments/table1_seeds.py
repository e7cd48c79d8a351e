"""Table 1's DT-family runs one seed at a time (issue 54).

The table gives each column's mean ± std over its seeds; with 2–3 seeds a reader wants the seeds themselves, how
long their rollouts lived (a fall ends an episode early: a low score with short rollouts is a policy that falls),
and which recording of the cell's dataset each seed trained on (a fresh machine records its own file of the same
recipe; docs/FIDELITY.md, *Datasets*). ``table1.summarise`` keeps each column's ``scores`` and ``lengths`` in its
seeds' order; this module turns them into ``table1.md``'s *Each seed*.
"""

from __future__ import annotations

from table1_report import DATASETS, ENVS, METHOD_NAMES, METHODS


def recording(entries: list[dict], seed: int) -> str:
    """``sha256 (dataset's own score)`` of the recording(s) the DT-family runs of ``seed`` trained on, from a cell's
    ``data_files`` entries."""
    xs = [x for x in entries if any(seed in x["seeds"].get(m, ()) for m in METHODS)]
    return ", ".join(f"{x['sha256']} ({x['dataset_score']:.1f})" for x in xs)


def _run(entry: dict | None, seed: int) -> str:
    """``score (mean length)`` of one column's run at ``seed``, '–' where it has none."""
    if entry is None or seed not in entry["seeds"]:
        return "–"
    i = entry["seeds"].index(seed)
    return f"{entry['scores'][i]:.1f} ({entry['lengths'][i]:.0f})"


def markdown(out: dict) -> str:
    """The *Each seed* section of ``table1.md`` from ``table1.summarise``'s ``out``: a row per cell and seed."""
    cols = [METHOD_NAMES[m] for m in METHODS]
    lines = ["", "## Each seed", "",
             "Each DT-family run's normalised score (mean over its evaluation episodes) and, in brackets, its "
             "rollouts' mean length in steps (1,000 = no fall), by training seed, with the recording of the dataset "
             "it trained on (sha256 of the episodes, the recording's own score). The table above gives their mean ± "
             "std.", "",
             "| dataset | env | seed | recording (own score) | " + " | ".join(cols) + " |",
             "|---|---|---|---|" + "---|" * len(cols)]
    for d in DATASETS:
        for e in ENVS:
            row, files = out["table"].get(f"{d}/{e}", {}), out.get("data_files", {}).get(f"{d}/{e}", [])
            for s in sorted({s for m in METHODS if m in row for s in row[m]["seeds"]}):
                lines.append(f"| {d} | {e} | {s} | {recording(files, s)} | "
                             + " | ".join(_run(row.get(m), s) for m in METHODS) + " |")
    return "\n".join(lines) + "\n"
