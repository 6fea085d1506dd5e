"""`rigtool show` on runs that lack what a sweep records (an imported table)."""

from __future__ import annotations

from rigtool.cli import main


def test_show_of_an_import_without_depth_or_seed(tmp_path, capsys):
    """An imported table records no depth and no simulator seed: `show` says so."""
    rows = ["Time (s),ESC signal (µs),Thrust (N),Motor Optical Speed (RPM)"]
    for i, command in enumerate(range(1500, 1901, 100)):
        rows += [f"{(i * 10 + k) * 0.1:.1f},{command},{(command - 1500) / 20},{command - 1500}"
                 for k in range(10)]
    log = tmp_path / "tyto.csv"
    log.write_text("\n".join(rows) + "\n", encoding="utf-8")
    db = str(tmp_path / "db.sqlite")
    assert main(["import", str(log), "--db", db, "--settle-s", "0.2"]) == 0
    capsys.readouterr()
    assert main(["show", "last", "--db", db]) == 0
    out = capsys.readouterr().out
    assert "not recorded" in out and "seed" not in out
