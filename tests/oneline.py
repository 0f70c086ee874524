"""The shape of every bad-input error, asserted the same way by every test module."""

# `lab train` and `lab sweep` say what they are about to do before the seconds of start-up; an
# error found after that line comes on the next. Nothing else may precede the error.
ANNOUNCEMENTS = ("train ", "resume ", "sweep ")


def assert_one_line_error(result, *phrases: str, exit_code: int = 2,
                          mid_run: bool = False) -> None:
    """`result` (a CliRunner result) ended with exit code 2 and one line `error: ...` on stderr,
    naming each of `phrases`; no traceback. `mid_run`: training's progress may come before."""
    assert result.exit_code == exit_code, result.output
    lines = result.stderr.splitlines()
    assert lines and lines[-1].startswith("error: "), result.stderr
    assert mid_run or all(line.startswith(ANNOUNCEMENTS) for line in lines[:-1]), result.stderr
    assert "Traceback" not in result.output
    for phrase in phrases:
        assert phrase in lines[-1], (phrase, result.stderr)
