"""``report.html``: one self-contained page for a safety reviewer (plots embedded as base64 PNG).

Sections: what was flown (scenarios, seed, counts), each configuration with its SHA-256, envelope table,
fence map and trigger distances against speed and heading, consistency warnings, the results per
expectation with Wilson intervals, the distributions, and the failures with their reproduction commands.
"""

from __future__ import annotations

import base64
import html
from collections.abc import Callable
from pathlib import Path
from typing import Any

from merlin.campaign import limits, plots
from merlin.campaign.spec import CampaignScenario
from merlin.config.loader import config_sha256
from merlin.config.summary import Table, envelope_table, format_cell

CSS = """
body{font-family:system-ui,-apple-system,'Segoe UI',sans-serif;margin:2em auto;max-width:1200px;color:#222;
background:#fff;line-height:1.4}
h1{border-bottom:3px solid #2a6;padding-bottom:.2em}h2{margin-top:1.8em;border-bottom:1px solid #ccc}
table{border-collapse:collapse;margin:.6em 0;font-size:.85em}td,th{border:1px solid #ccc;padding:.25em .5em;
text-align:left;vertical-align:top}th{background:#eef5ee}td.num{text-align:right;font-variant-numeric:tabular-nums}
.pass{color:#186b2e;font-weight:600}.fail{color:#b00020;font-weight:600}code{background:#f4f4f4;padding:0 .2em;
font-size:.85em;word-break:break-all}img{max-width:100%;border:1px solid #ddd;margin:.4em 0}
.warn{background:#fff4e0;border-left:4px solid #e90;padding:.4em .8em;margin:.3em 0}
.summary{font-size:1.15em;background:#f2f8f2;padding:.6em 1em;border-radius:4px}
"""


def _e(x: Any) -> str:
    return html.escape(str(x), quote=True)


def img(png: bytes | None, alt: str) -> str:
    if not png:
        return ""
    return f'<img alt="{_e(alt)}" src="data:image/png;base64,{base64.b64encode(png).decode("ascii")}">'


def figure(draw: Callable[..., bytes | None], alt: str, *args: Any) -> str:
    """``draw(*args)``'s figure as an ``<img>``, or a paragraph saying why it could not be drawn: matplotlib
    cannot place values near the largest float on an axis (a varied value sampled at 1e308 stopped the report
    with ``arange: cannot compute length``), and a figure must not cost the report its tables."""
    try:
        png = draw(*args)
    except (ValueError, OverflowError, FloatingPointError) as exc:
        plots.close_all()
        return (f'<p class="fail">The figure "{_e(alt)}" could not be drawn ({_e(type(exc).__name__)}: {_e(exc)}), '
                "most likely a value too large for an axis; the tables and results.jsonl hold every value.</p>")
    return img(png, alt)


def table_html(t: Table) -> str:
    head = "".join(f"<th>{_e(h)}</th>" for h in t.headers)
    body = []
    for row in t.rows:
        cells = []
        for c in row:
            num = isinstance(c, int | float) and not isinstance(c, bool)
            cells.append(f'<td class="num">{_e(format_cell(c))}</td>' if num else f"<td>{_e(format_cell(c))}</td>")
        body.append("<tr>" + "".join(cells) + "</tr>")
    return f"<table><caption>{_e(t.title)}</caption><tr>{head}</tr>{''.join(body)}</table>"


def rows_html(headers: list[str], rows: list[list[Any]]) -> str:
    head = "".join(f"<th>{_e(h)}</th>" for h in headers)
    body = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in r) + "</tr>" for r in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def config_section(cfg: Any, title: str) -> str:
    """Configuration, SHA-256, envelope table, fence map, trigger curves and warnings (review and report)."""
    parts = [f"<h3>{_e(title)}: <code>{_e(cfg.name)}</code></h3>",
             f"<p>SHA-256 of the effective configuration: <code>{config_sha256(cfg)}</code></p>",
             table_html(envelope_table(cfg)),
             img(plots.fence_map(cfg), "fence map"),
             img(plots.trigger_curves(cfg), "fence trigger distance against speed and heading"),
             table_html(limits.trigger_table(cfg))]
    found = limits.findings(cfg)
    if found:
        parts.append("<h4>Cross-checks: inconsistent settings</h4>")
        parts += [f'<div class="warn"><b>{_e(f.severity.value)} {_e(f.label)}</b>: {_e(f.text)} '
                  f'<small>({_e(", ".join(f.keys))})</small></div>' for f in found]
    else:
        parts.append("<p>No inconsistent settings found.</p>")
    return "\n".join(parts)


def _fmt(x: Any, digits: int = 3) -> str:
    if x is None:
        return "-"
    if isinstance(x, float):
        return f"{x:.{digits}g}"
    return _e(x)


#: Failed runs listed in the page itself; beyond this the full list is folded into a <details> element
#: (no script needed). campaign.json always holds every failed run.
MAX_FAILED_ROWS = 50
MAX_TRACEBACKS = 20


def failed_runs_html(failed: list[dict[str, Any]]) -> str:
    """Every failed or crashed run with its seed and reproduction command, in run order."""
    if not failed:
        return "<h3>All failed and crashed runs</h3><p>None.</p>"
    rows = [[_e(f["run_id"]), _e(f["seed"]), _e(f["status"] if f["status"] != "ok" else "failed"),
             _e(f["error"] or ", ".join(f["failed_expectations"]) or "-"),
             _e(", ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}"
                          for k, v in (f["samples"] or {}).items())),
             f"<code>{_e(f['reproduce'])}</code>"] for f in failed]
    head = ["run", "seed", "status", "failed expectations / error", "varied values", "reproduce"]
    title = f"<h3>All failed and crashed runs ({len(failed)})</h3>"
    if len(rows) <= MAX_FAILED_ROWS:
        return title + rows_html(head, rows)
    return (title + f"<p>The first {MAX_FAILED_ROWS} are listed; open the full list below (also in "
            "campaign.json, <code>failed_runs</code>).</p>" + rows_html(head, rows[:MAX_FAILED_ROWS])
            + f"<details><summary>all {len(rows)} failed and crashed runs</summary>" + rows_html(head, rows)
            + "</details>")


def render(agg: dict[str, Any], records: list[dict[str, Any]], scenarios: list[CampaignScenario]) -> str:
    ok_all = agg["passed"] == agg["runs"]
    lo, hi = agg["pass_rate_wilson95"]
    verdict = '<span class="pass">all runs passed</span>' if ok_all else '<span class="fail">failures found</span>'
    out = ["<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
           "<title>Merlin campaign report</title>", f"<style>{CSS}</style></head><body>",
           "<h1>Merlin campaign report</h1>",
           f'<p class="summary">{verdict}: {agg["runs"]} of {agg["runs_planned"]} planned runs flown; '
           f'{agg["passed"]} passed, {agg["failed"]} failed, {agg["errors"]} crashed (errors). '
           f"Pass rate Wilson 95 % interval [{lo:.4f}, {hi:.4f}]. Campaign seed {agg['seed']}. Estimator "
           f"(runs flown): {_e(', '.join(f'{k} {v}' for k, v in agg.get('estimators', {}).items()) or 'none')}.</p>"]
    out.append("<h2>Scenarios</h2>")
    out.append(rows_html(["file", "SHA-256", "configuration", "config SHA-256", "varied"], [
        [f"<code>{_e(s['file'])}</code>", f"<code>{_e(s['sha256'][:16])}</code>", _e(s["config_name"]),
         f"<code>{_e(s['config_sha256'])}</code>", "<br>".join(f"{_e(k)}: {_e(v)}" for k, v in s["vary"].items())]
        for s in agg["scenarios"]]))
    out.append("<h2>Configuration</h2><p>As the scenarios name it, before any varied key is applied "
               "(varied configuration keys are listed above and in each run's YAML).</p>")
    seen: set[str] = set()
    for cs in scenarios:
        sha = config_sha256(cs.base_config)
        if sha in seen:
            continue
        seen.add(sha)
        out.append(config_section(cs.base_config, f"Configuration of {cs.stem}"))
    out.append("<h2>Results per expectation</h2>")
    out.append(rows_html(["scenario", "expectation", "passed / runs", "pass rate", "Wilson 95 %"], [
        [_e(e["scenario"]), _e(e["name"]),
         f'<span class="{"pass" if e["passed"] == e["n"] else "fail"}">{e["passed"]} / {e["n"]}</span>',
         f"{e['pass_rate']:.4f}", f"[{e['wilson95'][0]:.4f}, {e['wilson95'][1]:.4f}]"] for e in agg["expectations"]]))
    out.append(figure(plots.pass_rates, "pass rates with Wilson intervals", agg))
    out.append("<h2>Distributions</h2>")
    out.append(rows_html(["metric", "n", "min", "5 %", "median", "95 %", "max"], [
        [_e(plots.METRIC_LABELS[k]), str(d.get("n", 0)), _fmt(d.get("min")), _fmt(d.get("p05")),
         _fmt(d.get("median")), _fmt(d.get("p95")), _fmt(d.get("max"))] for k, d in agg["distributions"].items()]))
    out.append(figure(plots.histograms, "distributions", records))
    if plots.varied_keys(records):
        out.append("<h3>Varied values against the minimum fence margin</h3>"
                   + figure(plots.samples_vs_margin, "samples against margin", records))
    out.append("<h2>Worst runs and failures</h2><p>Each command flies that single run again, bit for bit, "
               "from its resolved scenario (the configuration is inlined in the YAML).</p>")
    out.append(rows_html(["run", "seed", "status", "failed expectations / error", "max breach (m)",
                          "min margin (m)", "revocations", "varied values", "reproduce"], [
        [_e(w["run_id"]), _e(w["seed"]),
         f'<span class="{"pass" if w["passed"] else "fail"}">{_e(w["status"] if w["status"] != "ok" else ("passed" if w["passed"] else "failed"))}</span>',
         _e(w["error"] or ", ".join(w["failed_expectations"]) or "-"), _fmt(w["max_fence_breach_m"]),
         _fmt(w["min_fence_margin_m"]), _e("; ".join(w["revocations"]) or "-"),
         _e(", ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in (w["samples"] or {}).items())),
         f"<code>{_e(w['reproduce'])}</code>"] for w in agg["worst_runs"]]))
    out.append(failed_runs_html(agg.get("failed_runs", [])))
    errs = [r for r in records if r.get("status") == "error"]
    if errs:
        shown = sorted(errs, key=lambda r: r["index"])[:MAX_TRACEBACKS]
        more = f" (the first {len(shown)} of {len(errs)}; all are in results.jsonl)" if len(errs) > len(shown) else ""
        out.append(f"<h3>Crashed runs (tracebacks){more}</h3>")
        for r in shown:
            tb = r.get("traceback") or (f"No traceback: {r.get('error') or 'the run crashed'}. The process that "
                                        "could have written one is gone; the reproduction command above "
                                        "flies the run in the foreground.")
            out.append(f"<h4>{_e(r['run_id'])}</h4><pre>{_e(tb)}</pre>")
    t = agg.get("timing") or {}
    if "runs_per_min" in t:
        out.append(f"<h2>Timing</h2><p>{t['runs_flown']} runs in {t['wall_s']:.1f} s on {t['workers']} workers: "
                   f"{t['runs_per_min']:.1f} runs/min (this session only; machine load varies).</p>")
    out.append("</body></html>")
    return "\n".join(out)


def write_report(path: Path, agg: dict[str, Any], records: list[dict[str, Any]],
                 scenarios: list[CampaignScenario]) -> Path:
    tmp = path.with_suffix(".tmp")
    tmp.write_text(render(agg, records, scenarios), encoding="utf-8")
    tmp.replace(path)
    return path
