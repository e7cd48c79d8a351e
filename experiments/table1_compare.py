"""The DT-family table beside the one its model gave before the DT fix (issue 54).

Until 2026-12-06 the DT's return embedding had a zero bias (``dt_revision`` 1), which left the model unable to read
its return tokens; its DT-family results at a preset were moved to ``table1/<preset>-dt-rev1/`` as the record of
the defect. ``aggregate`` puts that table's per-cell means and averages beside today's, with each column's change
and the MinSubDT − DT verdicts of both.
"""

from __future__ import annotations

from table1_report import DATASETS, ENVS, METHOD_NAMES, METHODS, MINSUBDT_COLUMNS


def before_fix(preset: str) -> str:
    """The results folder of ``preset``'s DT-family runs before the fix."""
    return f"{preset}-dt-rev1"


def summary(out: dict) -> dict:
    """What the comparison keeps of the earlier table: per cell and DT-family column its mean, its averages, and
    the MinSubDT − DT verdicts."""
    return {"table": {k: {m: v[m]["mean"] for m in METHODS if m in v} for k, v in out["table"].items()},
            "averages": {k: {m: v[m]["mean"] for m in METHODS} for k, v in out["averages"].items()},
            "versus_dt": {k: {m: v[m]["verdict"] for m in MINSUBDT_COLUMNS if m in v}
                          for k, v in out["versus_dt"].items()},
            "dataset_score": dict(out["dataset_score"])}


def beats(table: dict, data: dict, m: str) -> tuple[int, int, int]:
    """``(above the data, above BC, cells)``: in how many cells with a mean of column ``m`` it is above the dataset's
    own score and above BC's mean (cells that have both)."""
    cells = [k for k, v in table.items() if m in v]
    mean = lambda v: v if isinstance(v, (int, float)) else v["mean"]  # noqa: E731  (a summary keeps the mean)
    above_data = sum(data.get(k) is not None and mean(table[k][m]) > data[k] for k in cells)
    above_bc = sum("bc" in table[k] and mean(table[k][m]) > mean(table[k]["bc"]) for k in cells)
    return above_data, above_bc, len(cells)


def matched_average(was: dict, now: dict, m: str, label: str, num, change) -> str:
    """Column ``m``'s average over the cells of ``label`` ("all", "without medium-replay") that today's table has,
    before → today, and over how many of the earlier cells: while the rerun lands cell by cell the two averages
    cover the same cells."""
    keep = (lambda k: not k.startswith("medium-replay/")) if "without medium-replay" in label else (lambda k: True)
    earlier = [k for k, v in was.items() if keep(k) and v.get(m) is not None]
    both = [k for k in earlier if m in now.get(k, {})]
    if not both:
        return num(sum(was[k][m] for k in earlier) / len(earlier)) if earlier else "–"
    a = sum(was[k][m] for k in both) / len(both)
    b = sum(now[k][m]["mean"] for k in both) / len(both)
    return f"{num(a)} → {change(b, a)}" + ("" if len(both) == len(earlier) else f", {len(both)} of {len(earlier)} cells")


def markdown(out: dict) -> str:
    """The report's section *Before the DT fix*, or nothing where no earlier table was kept."""
    old = out.get("before_dt_fix")
    if not old:
        return ""

    def num(x):
        return "–" if x is None else f"{x:.1f}"

    def change(new, was):
        return num(new) + (f" ({new - was:+.1f})" if new is not None and was is not None else "")

    cols = [METHOD_NAMES[m] for m in METHODS]
    lines = ["", "## Before the DT fix", "",
             f"The same columns from the model before the DT fix (`table1/{before_fix(out['preset'])}/`: its return "
             "embedding had a zero bias, so it barely read its return tokens; issue 54): earlier mean → today's "
             "(change). Cells not yet rerun show the earlier mean alone.", "",
             "| dataset | env | " + " | ".join(cols) + " |", "|---|---|" + "---|" * len(cols)]
    for d in DATASETS:
        for e in ENVS:
            was, now = old["table"].get(f"{d}/{e}", {}), out["table"].get(f"{d}/{e}", {})
            lines.append(f"| {d} | {e} | " + " | ".join(
                f"{num(was.get(m))} → {change(now[m]['mean'], was.get(m))}" if m in now else num(was.get(m))
                for m in METHODS) + " |")
    for label, av in old["averages"].items():
        lines.append(f"| **average ({label})** | | " + " | ".join(
            matched_average(old["table"], out["table"], m, label, num, change) for m in METHODS) + " |")
    lines += ["", "MinSubDT − DT verdicts, earlier → today (Welch, 2 SE; *Where MinSubDT is behind DT*):", "",
              "| dataset | env | " + " | ".join(f"{METHOD_NAMES[m]} − DT" for m in MINSUBDT_COLUMNS) + " |",
              "|---|---|" + "---|" * len(MINSUBDT_COLUMNS)]
    for d in DATASETS:
        for e in ENVS:
            was, now = old["versus_dt"].get(f"{d}/{e}", {}), out["versus_dt"].get(f"{d}/{e}", {})
            lines.append(f"| {d} | {e} | " + " | ".join(
                f"{was.get(m, '–')} → {now[m]['verdict'] if m in now else '–'}" for m in MINSUBDT_COLUMNS) + " |")
    lines.append("")
    for m in MINSUBDT_COLUMNS:
        was, now = beats(old["table"], old["dataset_score"], m), beats(out["table"], out["dataset_score"], m)
        lines.append(f"{METHOD_NAMES[m]}: above the data in {now[0]} of {now[2]} cells, above BC in {now[1]} "
                     f"(earlier: {was[0]} and {was[1]} of {was[2]}).")
    return "\n".join(lines) + "\n"
