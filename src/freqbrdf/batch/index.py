"""The batch's summary on disk: ``OUT/batch.json`` and ``OUT/index.html``.

`write_summary` writes both, atomically, after every capture: batch.json as `freqbrdf.batch.run`
returns the summary, index.html (`index_html`) as a table of every capture's status, seconds,
attempts, key metrics (coverage and mean entropy; the scores of docs/method.md#evaluation where the capture was
evaluated) and error, with links to the reports.
"""

from __future__ import annotations

import html
from pathlib import Path

from freqbrdf.fileio import atomic_path, write_json

BATCH_FILE = "batch.json"
INDEX_FILE = "index.html"
_COLUMNS = (  # (metric key, heading, digits)
    ("observed_fraction", "observed", None), ("entropy_mean", "mean entropy", 2),
    ("base_color_psnr", "base colour PSNR", 2), ("roughness_mae", "roughness MAE", 3),
    ("metallic_mae", "metallic MAE", 3), ("psnr_hdr", "PSNR-H", 2), ("psnr_ldr", "PSNR-L", 2),
    ("ssim", "SSIM", 3), ("lpips", "LPIPS", 3),
)


def index_html(summary: dict) -> str:
    """Render the batch's summary as index.html: one self-contained page.

    A table of every capture (status, seconds, attempts, the key metrics that any capture has, its
    error) with a link to its report, else to its summary.json.

    Parameters
    ----------
    summary : dict
        The batch's summary, as batch.json holds it (`freqbrdf.batch.run`).

    Returns
    -------
    str
        The HTML page.
    """
    def cell(value, digits):
        if value is None:
            return "<td></td>"
        if digits is None:
            return f"<td>{value:.0%}</td>"
        return f"<td>{value:.{digits}f}</td>"

    used = [column for column in _COLUMNS
            if any((row.get("metrics") or {}).get(column[0]) is not None for row in summary["captures"])]
    rows = []
    for row in summary["captures"]:
        name = html.escape(row["name"])
        link = row["paths"].get("report") or (f"{row['name']}/summary.json" if row["status"] in ("done", "skipped")
                                              else None)
        title = f'<a href="{html.escape(link)}">{name}</a>' if link else name
        metrics = row.get("metrics") or {}
        seconds = "" if row.get("seconds") is None else f"{row['seconds']:.1f}"
        rows.append(f'<tr class="{row["status"]}"><td>{title}</td><td>{row["status"]}</td><td>{seconds}</td>'
                    f'<td>{row.get("attempts") or ""}</td>'
                    + "".join(cell(metrics.get(key), digits) for key, _, digits in used)
                    + f'<td class="error">{html.escape(row.get("error") or "")}</td></tr>')
    counts = ", ".join(f"{count} {status}" for status, count in summary["counts"].items() if count)
    headings = "".join(f"<th>{html.escape(heading)}</th>" for _, heading, _ in used)
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>freqbrdf batch</title>
<style>
body {{ font-family: system-ui, sans-serif; margin: 2em; }}
table {{ border-collapse: collapse; }}
th, td {{ padding: 0.3em 0.7em; border-bottom: 1px solid #ddd; text-align: right; }}
th:first-child, td:first-child, td.error {{ text-align: left; }}
tr.failed td {{ color: #b00020; }}
tr.interrupted td, tr.pending td, tr.running td {{ color: #777; }}
</style></head><body>
<h1>freqbrdf batch</h1>
<p>Manifest <code>{html.escape(summary["manifest"])}</code>; {len(summary["captures"])} captures: {counts};
freqbrdf {html.escape(summary["freqbrdf"])}; started {html.escape(summary["started"])}{
    "" if summary["finished"] is None else ", finished " + html.escape(summary["finished"])}.
Seconds are each capture's time to make its outputs (for skipped ones, when they were made).</p>
<table><thead><tr><th>capture</th><th>status</th><th>seconds</th><th>attempts</th>{headings}<th>error</th></tr>
</thead><tbody>
{chr(10).join(rows)}
</tbody></table>
</body></html>
"""


def write_summary(out: Path, summary: dict) -> None:
    """Write ``OUT/batch.json`` and ``OUT/index.html``, each atomically.

    Parameters
    ----------
    out : Path
        The batch's output folder.
    summary : dict
        The batch's summary (`freqbrdf.batch.run`).
    """
    write_json(out / BATCH_FILE, summary)
    with atomic_path(out / INDEX_FILE) as tmp:
        tmp.write_text(index_html(summary), encoding="utf-8")
