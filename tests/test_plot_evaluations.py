"""a3c_tools.plot_evaluations draws a PNG from evaluations.csv and reports reaching a threshold."""

import subprocess
from pathlib import Path

from a3c_tools import plot_evaluations
from conftest import run_main

HEADER = "global_step,wall_time_s,mean_return,std_return,episodes\n"


def run(*args: str) -> subprocess.CompletedProcess:
    """`python -m a3c_tools.plot_evaluations *args`, in process."""
    return run_main(plot_evaluations.main, list(args), Path.cwd())


def test_plot_writes_png_and_reports_threshold(tmp_path):
    csv_path = tmp_path / "evaluations.csv"
    rows = ["0,1.0,0.2,0.4,50", "50000,30.0,0.86,0.35,50", "100000,61.5,0.94,0.24,50"]
    csv_path.write_text(HEADER + "\n".join(rows) + "\n")
    png = tmp_path / "curve.png"
    result = run(str(csv_path), "-o", str(png), "--threshold", "0.9")
    assert result.returncode == 0, result.stderr
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "first >= 0.9 at step 100,000, 62 s" in result.stdout
    assert "last 0.940 at step 100,000" in result.stdout


def test_plot_rejects_a_file_that_is_not_evaluations_csv(tmp_path):
    bad = tmp_path / "other.csv"
    bad.write_text("a,b\n1,2\n")
    result = run(str(bad), "-o", str(tmp_path / "x.png"))
    assert result.returncode == 2
    assert "not an evaluations.csv" in result.stderr


def test_plot_draws_references_and_rejects_a_malformed_one(tmp_path):
    csv_path = tmp_path / "evaluations.csv"
    csv_path.write_text(HEADER + "0,1.0,1.4,1.2,10\n500000,235.4,6.5,3.2,10\n")
    png = tmp_path / "curve.png"
    ok = run(str(csv_path), "-o", str(png), "--reference", "1.7=random", "--reference", "30")
    assert ok.returncode == 0, ok.stderr
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    bad = run(str(csv_path), "-o", str(tmp_path / "x.png"), "--reference", "random=1.7")
    assert bad.returncode == 2
    assert bad.stderr.startswith("error: --reference 'random=1.7' is not VALUE=LABEL")
    assert bad.stderr.count("\n") == 1


def png_size(path: Path) -> tuple[int, int]:
    """Width and height from a PNG's IHDR chunk."""
    header = path.read_bytes()[16:24]
    return int.from_bytes(header[:4], "big"), int.from_bytes(header[4:], "big")


def test_wall_time_panel_draws_a_second_panel(tmp_path):
    fast, slow = tmp_path / "fast.csv", tmp_path / "slow.csv"
    fast.write_text(HEADER + "0,1.0,1.4,1.2,10\n500000,235.4,6.5,3.2,10\n")
    slow.write_text(HEADER + "0,1.0,1.2,1.0,10\n500000,470.9,4.5,3.0,10\n")
    one, two = tmp_path / "one.png", tmp_path / "two.png"
    assert run(str(fast), str(slow), "-o", str(one)).returncode == 0
    result = run(str(fast), str(slow), "-o", str(two), "--wall-time", "--title", "t")
    assert result.returncode == 0, result.stderr
    (width_one, height_one), (width_two, height_two) = png_size(one), png_size(two)
    assert height_two == height_one and width_two > 1.4 * width_one


def x_labels() -> list[str]:
    """The x axis labels of the figure plot_evaluations drew, its axes' and their children's
    (a secondary axis is a child)."""
    import matplotlib.pyplot as plt

    (number,) = plt.get_fignums()
    axes = plt.figure(number).axes
    return [a.get_xlabel() for a in axes] + [c.get_xlabel() for a in axes for c in a.child_axes]


def test_a_wall_time_axis_only_with_wall_time(tmp_path, capsys):
    import matplotlib.pyplot as plt
    from a3c_tools import plot_evaluations

    csv_path = tmp_path / "evaluations.csv"
    csv_path.write_text(HEADER + "0,1.0,0.2,0.4,50\n50000,30.0,0.86,0.35,50\n")
    cases = {(): ["global steps"], ("--wall-time",): ["global steps", "wall time (minutes)"]}
    for flags, expected in cases.items():
        plt.close("all")
        assert plot_evaluations.main([str(csv_path), "-o", str(tmp_path / "c.png"), *flags]) == 0
        assert x_labels() == expected
    plt.close("all")
    assert "wrote" in capsys.readouterr().out
