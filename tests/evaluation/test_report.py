"""evaluation/report.py's plots: the Pareto front, and labels that stay readable where points crowd."""

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import pandas as pd  # noqa: E402
import pytest  # noqa: E402

from panorecon.evaluation.report import pareto, pareto_plot, place_labels  # noqa: E402


def test_pareto_front_keeps_the_points_nothing_beats_in_both():
    pts = [(1.0, 5.0), (2.0, 3.0), (3.0, 4.0), (4.0, 1.0), (2.0, 3.0)]
    # (3, 4) is beaten by (2, 3); equal points do not dominate each other
    assert pareto(pts) == [0, 1, 3, 4]


@pytest.mark.parametrize("n", [2, 5])
def test_labels_of_crowded_points_do_not_overlap(n):
    """The quick suite's averaged panel had fibonacci (9.7 s, 28.28 dB) and icosahedral (9.3 s, 28.17 dB) labels
    on top of each other; here n points within a label's height of each other."""
    fig, ax = plt.subplots(figsize=(6, 4))
    points = [(9.3 + 0.1 * k, 28.17 + 0.03 * k, f"source-{k}", "black") for k in range(n)]
    points.append((30.0, 21.5, "random", "black"))
    ax.scatter([p[0] for p in points], [p[1] for p in points])
    ax.set(xlim=(8, 30.5), ylim=(20, 30))
    ax.set_xscale("log")
    texts = place_labels(ax, points, fontsize=8)
    renderer = fig.canvas.get_renderer()
    boxes = [t.get_window_extent(renderer) for t in texts]
    assert sorted(t.get_text() for t in texts) == sorted(p[2] for p in points)
    assert not any(a.overlaps(b) for i, a in enumerate(boxes) for b in boxes[i + 1 :])
    frame = ax.get_window_extent(renderer)
    assert all(frame.x0 <= b.x0 and b.x1 <= frame.x1 for b in boxes)  # "random" sits at the right edge
    for (u, v), (x, y, _, _) in zip(ax.transData.transform([p[:2] for p in points]), points):
        assert not any(b.contains(u, v) for b in boxes), f"a label covers the marker at ({x}, {y})"
    plt.close(fig)


def test_pareto_plot_writes_one_png(tmp_path):
    per_run = pd.DataFrame(
        {
            "scene": ["bedroom", "bedroom", "beach", "beach"],
            "label": ["fibonacci", "icosahedral", "fibonacci", "icosahedral"],
            "sec_total": [9.7, 9.3, 9.9, 9.4],
            "psnr_ho": [32.1, 32.0, 24.4, 24.3],
        }
    )
    mean = per_run.groupby("label", sort=False)[["sec_total", "psnr_ho"]].mean()
    path = tmp_path / "pareto.png"
    pareto_plot(mean, per_run, "sec_total", "psnr_ho", "held-out PSNR (dB)", path, higher_is_better=True)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and not list(tmp_path.glob("*.tmp*"))


def test_provenance_names_the_commits_code_and_total_compute():
    from panorecon.evaluation.report import provenance_markdown

    frame = pd.DataFrame(
        {
            "commit": ["aaa", "aaa", "bbb", "aaa"],
            "code": ["c1", "c1", "c2", "c1"],
            "version_torch": ["2.13.0"] * 4,
            "cpu_points": [3600.0, 0.0, 1800.0, None],
            "cpu_train": [3600.0, 7200.0, 1800.0, None],  # the last row read n/a: no compute
            "sec_points": [10.0, 0.0, 0.0, None],
            "sec_train": [3590.0, 3600.0, 0.0, None],
            "load_train": [1.0, 2.5, 0.5, None],
        }
    )
    md = provenance_markdown(frame)
    assert "`aaa` (3), `bbb` (1)" in md and "`c1` (3), `c2` (1)" in md and "torch 2.13.0" in md
    assert "3 runs, 5.00 CPU hours, 2.00 wall hours" in md and "0.5–2.5" in md
    assert provenance_markdown(pd.DataFrame({"scene": ["x"]})) == ""
