# SPDX-License-Identifier: BSD-3-Clause
"""The batch's index: ``index.md`` and ``index.html`` in the output folder, one row per
recording linking its report, and ``batch.json`` with every outcome (machine-readable)."""

from __future__ import annotations

import html
import json
import os
from pathlib import Path

COLUMNS = ("recording", "status", "stations", "map points", "recording s", "processing s",
           "report / error")


def _report_link(outdir: Path, o: dict) -> str | None:
    """The report's path relative to ``outdir`` (None: no report)."""
    rep = Path(o["outdir"]) / "report.md"
    files = (o.get("summary") or {}).get("files") or {}
    if "report" in files:
        rep = Path(files["report"])
    return os.path.relpath(rep, outdir) if rep.is_file() else None


def row(o: dict) -> list[str]:
    """A recording's cells (without the link column)."""
    s = o.get("summary") or {}

    def num(key, fmt):
        return format(s[key], fmt) if key in s else "–"

    return [o["name"], o["status"], num("stations", "d"), num("map_points", ",d"),
            num("recording_s", ".1f"), num("processing_s", ".1f")]


def write_index(outdir: Path, outcomes: list[dict], meta: dict) -> dict[str, Path]:
    """Write index.md, index.html and batch.json; return their paths."""
    outdir.mkdir(parents=True, exist_ok=True)
    counts = {k: sum(o["status"] == k for o in outcomes) for k in ("done", "skipped", "failed")}
    head = (f"{len(outcomes)} recordings: {counts['done']} reconstructed, "
            f"{counts['skipped']} up to date (skipped), {counts['failed']} failed; "
            f"engine: {meta.get('engine', '')}; wall {meta.get('wall_s', 0.0):.1f} s")

    merged_md = merged_html = ""
    m = meta.get("merge")
    if m:
        rel = os.path.relpath(Path(m["folder"]) / "report.md", outdir)
        comps = m["components"]
        text = (f"merged model: {m['merged_stations']} of {m['stations']} stations, "
                f"{len(comps[0]['recordings']) if comps else 0} recordings joined by "
                f"{m['links_kept']} links; {len(comps)} component(s)")
        if m.get("recording_pairs_left_out"):
            text += f"; {m['recording_pairs_left_out']} recording pairs left out by the shortlist"
        if m.get("recording_pairs_proximity"):
            text += (f"; {m['recording_pairs_proximity']} recording pairs linked by proximity "
                     f"(from the merged estimate)")
        merged_md = f"{text}: [report]({rel})\n\n"
        merged_html = f'<p>{html.escape(text)}: <a href="{html.escape(rel)}">report</a></p>'
    md = ["# tripod batch", "", head, "", merged_md + "| " + " | ".join(COLUMNS) + " |",
          "|" + "---|" * len(COLUMNS)]
    rows_html = []
    for o in outcomes:
        cells = row(o)
        link = _report_link(outdir, o)
        if o["status"] == "failed":
            last_md = o["error"].replace("|", "\\|")
            last_html = html.escape(o["error"])
        elif link:
            last_md = f"[report]({link})"
            last_html = f'<a href="{html.escape(link)}">report</a>'
        else:
            last_md = last_html = "(no report)"
        md.append("| " + " | ".join(cells + [last_md]) + " |")
        rows_html.append("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in cells)
                         + f"<td>{last_html}</td></tr>")
    md.append("")
    page = ("<!doctype html><html><head><meta charset='utf-8'><title>tripod batch</title>"
            "<style>body{font-family:sans-serif}td,th{padding:2px 8px;border-bottom:1px solid "
            "#ccc}</style></head><body><h1>tripod batch</h1>"
            f"<p>{html.escape(head)}</p>{merged_html}<table><tr>"
            + "".join(f"<th>{html.escape(c)}</th>" for c in COLUMNS) + "</tr>"
            + "".join(rows_html) + "</table></body></html>\n")
    paths = {"md": outdir / "index.md", "html": outdir / "index.html",
             "json": outdir / "batch.json"}
    paths["md"].write_text("\n".join(md))
    paths["html"].write_text(page)
    paths["json"].write_text(json.dumps({**meta, "counts": counts, "recordings": outcomes},
                                        indent=1, default=str))
    return paths
