"""report.html: one self-contained page for an ablation (inline CSS and JS, images as data URIs, no network).

It holds the averaged and per-scene tables (click a header to sort), pareto.png and psnr_vs_iterations.png,
and per row a strip of thumbnails: render | pseudo-label and render | held-out truth (the trainer's
renders/label_0.png and heldout_0.png) and a screenshot of the row's initial point cloud.
"""

from __future__ import annotations

import base64
import html
import math
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from ..io import atomic_write
from .report import COMPARISON_NOTE, PAPER_NOTE, TABLE_COLUMNS, average_table, comparison_tables, design_cell, with_seed

CSS = """body{font:14px/1.4 system-ui,sans-serif;margin:24px;color:#222;max-width:1400px}
table{border-collapse:collapse;margin:8px 0 20px}th,td{border:1px solid #ccc;padding:3px 8px;text-align:right}
th{background:#eee;cursor:pointer;user-select:none}th:first-child,td:first-child{text-align:left}
th.asc::after{content:" \\25B2"}th.desc::after{content:" \\25BC"}
img.plot{max-width:100%;border:1px solid #ddd}.strip img{height:96px;image-rendering:pixelated;margin-right:6px}
.strip figure{display:inline-block;margin:0 8px 8px 0}.strip figcaption{font-size:11px;color:#555}
.na{color:#999}"""

JS = """document.querySelectorAll('table.sortable th').forEach((th,i)=>th.addEventListener('click',()=>{
const tb=th.closest('table').tBodies[0],rows=[...tb.rows],asc=!th.classList.contains('asc');
th.closest('tr').querySelectorAll('th').forEach(h=>h.classList.remove('asc','desc'));
th.classList.add(asc?'asc':'desc');
const key=r=>{const c=r.cells[i],v=c.dataset.v;return v===undefined?c.textContent:parseFloat(v);};
rows.sort((a,b)=>{const x=key(a),y=key(b);
if(typeof x==='number'&&isNaN(x))return 1;if(typeof y==='number'&&isNaN(y))return -1;
return (x<y?-1:x>y?1:0)*(asc?1:-1);});rows.forEach(r=>tb.appendChild(r));}));"""


@dataclass
class RowAssets:
    """Where one results row's pictures are: the trainer's renders/ folder (or None), its cloud (or None) and
    the cloud's stage key (names its cached screenshot)."""

    renders: Path | None
    cloud: Path | None
    key: str = "cloud"


def data_uri(png: Path) -> str:
    return "data:image/png;base64," + base64.b64encode(Path(png).read_bytes()).decode("ascii")


def _table(table: pd.DataFrame, label_header: str) -> str:
    heads = [(c, h, f) for c, h, f in TABLE_COLUMNS if c in table]
    seeded = "seeds" in table and (table["seeds"] > 1).any()
    out = [
        "<table class=sortable><thead><tr>",
        f"<th>{html.escape(label_header)}</th><th>{'scenes × seeds' if seeded else 'scenes'}</th>",
        "".join(f"<th>{html.escape(h)}</th>" for _, h, _ in heads),
        "</tr></thead><tbody>",
    ]
    for label, r in table.iterrows():
        cells = [
            f"<td>{html.escape(str(label))}</td>",
            f"<td data-v='{int(r['runs'])}'>{html.escape(design_cell(r))}</td>",
        ]
        for c, _, f in heads:
            v, hw = r[c], r.get(f"{c}_hw", math.nan)
            ok = v is not None and not (isinstance(v, float) and math.isnan(v))
            pm = f" ± {f.format(hw)}" if ok and not math.isnan(hw) else ""
            cells.append(
                f"<td data-v='{float(v)!r}'>{f.format(v)}{pm}</td>" if ok else "<td data-v='NaN' class=na>n/a</td>"
            )
        out.append("<tr>" + "".join(cells) + "</tr>")
    out.append("</tbody></table>")
    return "".join(out)


def _plain_table(headers: list, rows: list) -> str:
    """A sortable table of text cells (sorted as text)."""
    return (
        "<table class=sortable><thead><tr>"
        + "".join(f"<th>{html.escape(str(h))}</th>" for h in headers)
        + "</tr></thead><tbody>"
        + "".join("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in r) + "</tr>" for r in rows)
        + "</tbody></table>"
    )


def cloud_thumbnail(cloud: Path, out: Path) -> Path:
    """A 480x300 pyvista screenshot of ``cloud`` at ``out`` (made once; a rerun reuses it)."""
    if not out.exists():
        from ..geometry import PointCloud
        from ..viz import screenshot

        screenshot(PointCloud.load_ply(cloud), out, window_size=(480, 300))
    return out


def _strip(row: pd.Series, assets: RowAssets, thumbs: Path) -> str:
    figs = []
    for name, caption in (("label_0.png", "render | pseudo-label"), ("heldout_0.png", "render | held-out truth")):
        p = assets.renders / name if assets.renders is not None else None
        if p is not None and p.exists():
            figs.append(f"<figure><img alt='{caption}' src='{data_uri(p)}'><figcaption>{caption}</figcaption></figure>")
    if assets.cloud is not None and assets.cloud.exists():
        try:
            png = cloud_thumbnail(assets.cloud, thumbs / f"{assets.key}.png")
            figs.append(
                f"<figure><img alt='point cloud' src='{data_uri(png)}'><figcaption>initial point cloud"
                "</figcaption></figure>"
            )
        except Exception as e:  # no OpenGL here: the page says so rather than failing the ablation
            figs.append(f"<figure class=na>n/a: cloud screenshot failed ({html.escape(str(e)[:120])})</figure>")
    if not figs:
        return ""
    return (
        f"<div class=strip><h4>{html.escape(str(row['label']))} &middot; {html.escape(str(row['scene']))}</h4>"
        + "".join(figs)
        + "</div>"
    )


def write_report_html(
    frame: pd.DataFrame, suite, out: Path, assets: list[RowAssets] | None, wall_seconds: float
) -> Path:
    """DIR/report.html from results ``frame`` (one row per run, in ``assets``' order; None: no pictures) and
    DIR's plots."""
    out = Path(out)
    frame = with_seed(frame)
    head = " / ".join(suite.row_columns)
    seeds = sorted(set(frame["seed"]))
    reference = getattr(suite, "reference", None)
    tables = comparison_tables(frame, reference, head, suite.margins, suite.paper_figures()) if reference else []
    parts = [
        f"<!doctype html><html><head><meta charset=utf-8><title>{html.escape(suite.title)}</title>",
        f"<style>{CSS}</style></head><body><h1>{html.escape(suite.title)}</h1>",
        f"<p>Suite <code>{html.escape(str(suite.path))}</code>: {len(frame)} runs over "
        f"{frame['scene'].nunique()} scenes and {len(seeds)} seed{'s' if len(seeds) > 1 else ''}; this invocation "
        f"took {wall_seconds:.1f} s. PSNR/SSIM/LPIPS without "
        "a prefix: pseudo-label protocol; held-out: true renders away from the panorama centre. "
        + ("Cells: mean ± half-width of its 95 % interval over seeds, the scenes fixed. " if len(seeds) > 1 else "")
        + "Click a column header to sort.</p>",
        "<h2>Averaged over scenes" + (" and seeds" if len(seeds) > 1 else "") + "</h2>",
        _table(average_table(frame), head),
    ]
    if tables:
        parts += [
            f"<h2>Against the reference: {html.escape(reference)}</h2>",
            f"<p>{html.escape(COMPARISON_NOTE.format(ref=reference)).replace('*', '')}</p>",
            _plain_table(*tables[0]),
            "<p>Every metric, these scenes:</p>",
            _plain_table(*tables[1]),
        ]
        if len(tables) > 2:
            parts += [f"<p>{html.escape(PAPER_NOTE.format(ref=reference))}</p>", _plain_table(*tables[2])]
    for title, name in (("Error against run time", "pareto.png"), ("PSNR against steps", "psnr_vs_iterations.png")):
        if (out / name).exists():
            parts += [f"<h2>{title}</h2>", f"<img class=plot alt='{name}' src='{data_uri(out / name)}'>"]
    parts.append("<h2>Per scene</h2>")
    for scene, g in frame.groupby("scene", sort=False):
        parts += [f"<h3>{html.escape(str(scene))}</h3>", _table(average_table(g), head)]
    strips = [_strip(r, a, out / "thumbs") for (_, r), a in zip(frame.iterrows(), assets or [])]
    if any(strips):
        parts += ["<h2>Every run</h2>"] + strips
    parts.append(f"<script>{JS}</script></body></html>")
    with atomic_write(out / "report.html") as tmp:
        Path(tmp).write_text("".join(parts), encoding="utf-8")
    return out / "report.html"
