"""Progress lines on stderr: the `Progress` helper, and what select, fit and the CLI report with it."""

import io as stdio
from pathlib import Path

import pytest

from brdffit import fit, select, synth
from brdffit.cli import EXIT_OK, main
from brdffit.progress import Progress

CLAY = Path(__file__).resolve().parents[1] / "data" / "synthetic" / "clay.h5"


class _Terminal(stdio.StringIO):
    def isatty(self):
        return True


def test_progress_on_a_pipe_writes_whole_lines_every_ten_percent_and_on_new_details():
    stream = stdio.StringIO()
    bar = Progress("MCMC", 200, unit="steps", stream=stream)
    for step in range(1, 201):
        bar.update(step)
    bar.update(200, "tail")
    bar.close("(8 walkers)")
    lines = stream.getvalue().splitlines()
    # 0% (the first step), 10%, ..., 100%, then the detail line, then the closing line: no flood of 200 lines.
    assert [line.split()[1] for line in lines[:11]] == ["1/200"] + [f"{20 * k}/200" for k in range(1, 11)]
    assert lines[11].startswith("MCMC 200/200 steps (100%)") and lines[11].endswith("tail")
    assert lines[12].startswith("MCMC done in ") and lines[12].endswith("(8 walkers)")
    assert len(lines) == 13


def test_progress_on_a_terminal_redraws_one_line():
    stream = _Terminal()
    bar = Progress("select", 4, stream=stream)
    for i in range(4):
        bar.update(i, f"fitting candidate {i}")
    bar.close("chose candidate 2")
    text = stream.getvalue()
    assert text.count("\r\033[K") == 5 and text.count("\n") == 1
    assert "select 3/4 (75%)" in text and text.endswith("chose candidate 2\n")


def test_disabled_progress_prints_nothing():
    stream = stdio.StringIO()
    bar = Progress("fit", 3, enabled=False, stream=stream)
    bar.update(1, "x")
    bar.close()
    assert stream.getvalue() == ""


def test_select_reports_each_candidate(capsys):
    data = synth.generate("lambert", n=300, noise="relative:0.01", seed=0)
    select(data, ["lambert", "oren-nayar"], progress=True)
    err = capsys.readouterr().err
    assert "select 0/2 fits (0%)" in err and "fitting lambert" in err
    assert "select 1/2 fits (50%)" in err and "fitting oren-nayar" in err
    assert "select done in" in err and "chose lambert" in err


def test_fit_reports_its_stages_and_the_number_of_starts(capsys):
    data = synth.generate("lambert+ggx", n=400, noise="relative:0.01", seed=0)
    result = fit(data, "lambert+ggx", multistart=3, progress=True)
    err = capsys.readouterr().err
    assert "fit lambert+ggx 0/4 stages" in err and "search" in err
    # The search's separated candidates plus the 3 quasi-random starts, all polished in one batch.
    assert f"polishing {len(result.starts)} starts" in err
    assert f"{result.status}, cost" in err
    fit(data, "lambert+ggx")
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize("flag, shown", [([], True), (["--json"], False), (["--quiet"], False)])
def test_cli_fit_shows_progress_unless_quiet_or_json(flag, shown, tmp_path, capsys):
    code = main(["fit", str(CLAY), "--model", "lambert", "--no-report", "--out", str(tmp_path / "o"), *flag])
    assert code == EXIT_OK
    assert ("fit lambert" in capsys.readouterr().err) == shown
