"""``merlin demo [--out DIR]``: the Quickstart's main job.

Flies a demo set of the shipped scenarios on built-in defaults -- a nominal handover, the paper's
Figure 5 (envelope exceedance with a 1 s duration), Figure 4 (a fence approach with and without velocity
projection), a crashed controller, an operator flying at the fence, and GPS lost together with the ground
link -- and writes one self-contained HTML report (plots embedded) beside each run's own outputs.
"""

from __future__ import annotations

import argparse
import base64
import html
import json
import os
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

DEMO_SET = (
    "nominal",
    "figure5_delayed",
    "figure4_projection_9mps",
    "figure4_position_only_9mps",
    "controller_crash",
    "operator_fence",
    "gps_and_gcs_loss",
)



def _periods(s: dict[str, Any]) -> str:
    """The tick and the periods a summary says were flown: the core's and the voter's and filter's."""
    p = s.get("periods") or {}
    if not p:
        return ""
    return (f"simulation tick {p['tick_s'] * 1e3:g} ms, trusted core every {p['core_s'] * 1e3:g} ms, "
            f"IMU voter and estimator every {p['nav_s'] * 1e3:g} ms")

def _scenarios_dir() -> Path:
    from merlin.resources import scenarios_dir  # the repository's, or the wheel's copy

    return scenarios_dir()


def register(sub: Any) -> None:
    p = sub.add_parser("demo", help="fly the demo scenarios and write a report with plots")
    p.add_argument("--out", default="out/demo", help="output directory (default: out/demo)")
    p.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1))
    p.add_argument("--only", nargs="*", default=None, help="a subset of the demo scenarios, by name")
    p.set_defaults(func=run)


def _fly(name: str, out: str) -> dict[str, Any]:
    from merlin.commands.sim import run_one

    return run_one(str(_scenarios_dir() / f"{name}.yaml"), Path(out) / name, plots=True, quiet=True)


def _img(path: Path) -> str:
    if not path.exists():
        return ""
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    return f'<img alt="{html.escape(path.stem)}" src="data:image/png;base64,{data}">'


def write_report(out: Path, summaries: list[dict[str, Any]], wall_s: float) -> Path:
    rows = []
    sections = []
    for s in summaries:
        name = s["scenario"]
        ok = s["passed"]
        rows.append(
            f"<tr class={'pass' if ok else 'fail'}><td><a href='#{name}'>{html.escape(name)}</a></td>"
            f"<td>{html.escape(s['description'])}</td><td>{'passed' if ok else 'FAILED'}</td>"
            f"<td>{s['metrics']['max_fence_breach_m']:.2f}</td><td>{s['metrics']['min_fence_margin_m']:.1f}</td>"
            f"<td>{s['timing']['realtime_factor']:.1f}x</td></tr>"
        )
        exp = "".join(
            f"<li class={'pass' if x['passed'] else 'fail'}>{'PASS' if x['passed'] else 'FAIL'}: "
            f"{html.escape(x['name'])} &mdash; {html.escape(x['detail'])}</li>"
            for x in s["expectations"]
        )
        auth = "".join(
            f"<li>t={e['t']:.3f} s: {e.get('from', '')} &rarr; {e.get('to', '')} "
            f"({html.escape(e.get('reason_detail', {}).get('text', e.get('reason', '')))})</li>"
            for e in s["events"]
            if e["type"] == "authority"
        )
        d = out / name
        sections.append(
            f"<section id='{name}'><h2>{html.escape(name)}</h2><p>{html.escape(s['description'])}</p>"
            f"<p class=small>configuration {html.escape(s['config_name'])}, SHA-256 <code>{s['config_sha256']}</code>;"
            f" seed {s['seed']}; estimator {html.escape(s['estimator'])} ({html.escape(s['estimator_note'])});"
            f" {_periods(s)}</p>"
            f"<h3>Expectations</h3><ul>{exp}</ul><h3>Authority changes</h3><ul>{auth}</ul>"
            f"<div class=plots>{_img(d / 'ground_track.png')}{_img(d / 'authority.png')}</div>"
            f"<details><summary>Envelope parameters against their limits</summary>{_img(d / 'envelope.png')}</details>"
            f"<p class=small>Reproduce: <code>merlin sim examples/scenarios/{name}.yaml --out {name}</code>;"
            f" full outputs in <code>{html.escape(str(d))}</code> (summary.json, log.parquet, events.jsonl).</p>"
            f"</section>"
        )
    passed = sum(1 for s in summaries if s["passed"])
    doc = f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>Merlin demo report</title>
<style>
body {{ font-family: system-ui, sans-serif; margin: 2em auto; max-width: 1100px; color: #222; }}
table {{ border-collapse: collapse; width: 100%; }} td, th {{ border: 1px solid #ccc; padding: 4px 8px; }}
tr.pass td:nth-child(3), li.pass {{ color: #1a7f37; }} tr.fail td:nth-child(3), li.fail {{ color: #b42318; }}
img {{ max-width: 100%; }} .plots img {{ max-width: 49%; vertical-align: top; }} .small {{ color: #555; font-size: 0.9em; }}
section {{ border-top: 2px solid #ddd; margin-top: 2em; }} code {{ font-size: 0.85em; }}
</style></head><body>
<h1>Merlin demo: a trusted autopilot supervising experimental controllers</h1>
<p>{passed} of {len(summaries)} scenarios met all their expectations. Closed-loop simulation (multirotor
dynamics at 400 Hz, sensors, the trusted core, Merlin's inner loops); total wall time {wall_s:.0f} s.</p>
<table><tr><th>scenario</th><th>what it shows</th><th>result</th><th>max fence breach [m]</th>
<th>min fence margin [m]</th><th>speed</th></tr>{''.join(rows)}</table>
{''.join(sections)}
</body></html>
"""
    p = out / "report.html"
    p.write_text(doc, encoding="utf-8")
    (out / "demo.json").write_text(json.dumps({"passed": passed, "total": len(summaries),
                                               "scenarios": [s["scenario"] for s in summaries]}, indent=2) + "\n")
    return p


def run(args: argparse.Namespace) -> int:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    names = list(args.only) if args.only else list(DEMO_SET)
    unknown = [n for n in names if not (_scenarios_dir() / f"{n}.yaml").exists()]
    if unknown:
        print(f"merlin demo: unknown scenario(s) {unknown}; shipped: "
              f"{sorted(p.stem for p in _scenarios_dir().glob('*.yaml'))}")
        return 2
    print(f"merlin demo: flying {len(names)} scenarios with {args.workers} worker(s) -> {out}/", flush=True)
    t0 = time.perf_counter()
    summaries: dict[str, dict[str, Any]] = {}
    if args.workers > 1:
        with ProcessPoolExecutor(max_workers=args.workers) as pool:
            futures = {pool.submit(_fly, n, str(out)): n for n in names}
            for fut in futures:
                n = futures[fut]
                summaries[n] = fut.result()
                print(f"  {n}: {'passed' if summaries[n]['passed'] else 'FAILED'}", flush=True)
    else:
        for n in names:
            summaries[n] = _fly(n, str(out))
            print(f"  {n}: {'passed' if summaries[n]['passed'] else 'FAILED'}", flush=True)
    ordered = [summaries[n] for n in names]
    report = write_report(out, ordered, time.perf_counter() - t0)
    print(f"report: {report}")
    for n in names:
        print(f"  plots: {out / n / 'ground_track.png'}, {out / n / 'authority.png'}, {out / n / 'envelope.png'}")
    return 0 if all(s["passed"] for s in ordered) else 1
