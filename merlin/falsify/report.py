"""What a falsification leaves in its directory: the worst cases as scenario files, every evaluation, and a
summary (markdown and HTML) with the margin distribution per adversary class and the best-so-far curve."""

from __future__ import annotations

import html
import json
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from merlin.falsify.search import Evaluation, SearchResult


def write_scenario(path: Path, ev: Evaluation, header: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    text = "".join(f"# {line}\n" for line in header.splitlines())
    path.write_text(text + yaml.safe_dump(ev.scenario, sort_keys=False), encoding="utf-8")


def margin_stats(evs: list[Evaluation]) -> dict[str, Any]:
    m = np.array([e.margin_m for e in evs if e.status == "ok" and e.margin_m is not None], dtype=float)
    if not m.size:
        return {"runs": 0}
    q = np.percentile(m, [0, 5, 25, 50, 75, 100])
    return {"runs": int(m.size), "breaches": int((m < 0).sum()), "min_m": float(q[0]), "p5_m": float(q[1]),
            "p25_m": float(q[2]), "median_m": float(q[3]), "p75_m": float(q[4]), "max_m": float(q[5])}


def best_so_far(evs: list[Evaluation]) -> list[float]:
    out, best = [], float("inf")
    for e in evs:
        best = min(best, e.objective)
        out.append(best)
    return out


def figures(result: SearchResult) -> dict[str, bytes]:
    from merlin.campaign.plots import _png, plt

    evs = result.evaluations
    classes = list(dict.fromkeys(e.adversary for e in evs))
    fig, ax = plt.subplots(figsize=(7, 3.6))
    for c in classes:
        m = [e.margin_m for e in evs if e.adversary == c and e.status == "ok" and e.margin_m is not None]
        if m:
            ax.hist(np.clip(m, -50, 200), bins=60, range=(min(-5.0, min(m)), min(max(m), 200.0)),
                    histtype="step", lw=1.4, label=c)
    ax.axvline(0.0, color="k", lw=0.8)
    ax.set_xlabel("stop margin: least signed fence margin of the run [m] (negative: breach)")
    ax.set_ylabel("runs")
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    hist = _png(fig)
    fig, ax = plt.subplots(figsize=(7, 3.6))
    ax.plot(np.arange(1, len(evs) + 1), best_so_far(evs), color="k", lw=1.6, label="all classes")
    for c in classes:
        sub = [e for e in evs if e.adversary == c]
        ax.plot([e.index + 1 for e in sub], best_so_far(sub), lw=1.0, label=c)
    ax.axhline(0.0, color="tab:red", lw=0.8)
    ax.set_xlabel("evaluations (simulations)")
    ax.set_ylabel("least margin so far [m]")
    ax.set_yscale("symlog", linthresh=1.0)
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    return {"margins.png": hist, "best_so_far.png": _png(fig)}


def reproduction(worst: dict[str, Any]) -> str:
    """What ``merlin sim`` gave on the written worst case: its margin, or that it did not fly (the summary
    is written either way: a reproduction that fails is reported, not hidden)."""
    m = worst.get("reproduced_margin_m")
    if m is None:
        return "**`merlin sim` did not reproduce it** (the run failed: see the error above the summary)"
    return f"reproduced by `merlin sim` at {m:.3f} m"


def markdown(summary: dict[str, Any]) -> str:
    s = summary
    lines = [f"# merlin falsify: {s['config']}", "",
             f"Vehicle {s['vehicle']}, estimator {s.get('estimator', 'unrecorded')}, budget {s['budget']} simulations ({s['evaluated']} flown, {s['errors']} errors), "
             f"seed {s['seed']}, {s['workers']} workers on the {s['backend']} backend, {s['wall_s']:.0f} s "
             f"({s['runs_per_min']:.1f} runs/min).", ""]
    w = s.get("worst")
    if w:
        verdict = "BREACH" if w["margin_m"] < 0 else "no breach"
        lines += [f"**Smallest stop margin found: {w['margin_m']:.3f} m ({verdict})**, adversary "
                  f"`{w['adversary']}` (evaluation {w['index']}); {reproduction(w)}.", "",
                  "```", w["command"], "```", ""]
    lines += ["| adversary | runs | breaches | least margin [m] | 5 % | median | restarts | worst case |",
              "|---|---:|---:|---:|---:|---:|---:|---|"]
    for c, st in s["classes"].items():
        if not st.get("runs"):
            lines.append(f"| {c} | 0 | | | | | | |")
            continue
        lines.append(f"| {c} | {st['runs']} | {st['breaches']} | {st['min_m']:.2f} | {st['p5_m']:.2f} | "
                     f"{st['median_m']:.2f} | {st['restarts']} | `{st['worst_file']}` |")
    lines += ["", "![margins](margins.png)", "", "![best so far](best_so_far.png)", ""]
    return "\n".join(lines)


def write_html(path: Path, md_text: str, pngs: dict[str, bytes]) -> None:
    import base64

    body = []
    in_code = False
    for line in md_text.splitlines():
        if line.startswith("```"):
            body.append("</pre>" if in_code else "<pre>")
            in_code = not in_code
        elif in_code:
            body.append(html.escape(line))
        elif line.startswith("!["):
            name = line[line.index("(") + 1: line.index(")")]
            if name in pngs:
                body.append(f'<img alt="{html.escape(name)}" src="data:image/png;base64,'
                            f'{base64.b64encode(pngs[name]).decode("ascii")}">')
        elif line.startswith("# "):
            body.append(f"<h1>{html.escape(line[2:])}</h1>")
        elif line.startswith("|---"):
            continue
        elif line.startswith("|"):
            cells = [html.escape(c.strip().strip("`")) for c in line.strip("|").split("|")]
            body.append("<tr>" + "".join(f"<td>{c}</td>" for c in cells) + "</tr>")
        elif line:
            body.append(f"<p>{html.escape(line).replace('**', '')}</p>")
    rows = [i for i, b in enumerate(body) if b.startswith("<tr>")]
    if rows:  # the one table: its rows are consecutive
        body.insert(rows[-1] + 1, "</table>")
        body.insert(rows[0], "<table>")
    text = "\n".join(body)
    path.write_text("<!doctype html><meta charset=utf-8><title>merlin falsify</title>"
                    "<style>body{font-family:sans-serif;max-width:60em}td{padding:2px 8px;border-bottom:1px solid #ddd}"
                    "</style>\n" + text + "\n", encoding="utf-8")


def write_outputs(out: Path, summary: dict[str, Any], result: SearchResult) -> None:
    with (out / "evaluations.jsonl").open("w", encoding="utf-8") as f:
        for e in result.evaluations:
            f.write(json.dumps(e.record(), sort_keys=True) + "\n")
    (out / "falsify.json").write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
    pngs = figures(result)
    for name, data in pngs.items():
        (out / name).write_bytes(data)
    md_text = markdown(summary)
    (out / "summary.md").write_text(md_text, encoding="utf-8")
    write_html(out / "summary.html", md_text, pngs)
