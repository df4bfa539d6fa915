"""The console's working directory: its default, the wizard's paths under it, the options of
``beamrelay console`` and ``up`` that set it, and bad input as one line."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import pytest

from planner.console.wizard import Wizard
from planner.console.workdir import default_workdir, ensure_dir, output_path
from planner.errors import InputError
from planner.service.up import child_commands
from tests import cli_run
from tests.drivers.conftest import free_port
from tests.paths import REPO, SCENARIOS

N1 = SCENARIOS / "paper_n1.yaml"


def test_the_default_is_the_users_data_folder_never_the_repository(tmp_path: Path) -> None:
    assert default_workdir({"XDG_DATA_HOME": str(tmp_path)}) == tmp_path / "beamrelay/console"
    home = Path.home() / ".local/share/beamrelay/console"
    assert default_workdir({}) == home
    assert default_workdir({"XDG_DATA_HOME": "relative/dir"}) == home  # the XDG rule
    assert not default_workdir().is_relative_to(REPO)


def test_relative_names_go_under_the_workdir_and_bad_ones_are_input_errors(
    tmp_path: Path,
) -> None:
    wd = ensure_dir(tmp_path / "a" / "wd", "--workdir")
    assert wd.is_dir()
    assert output_path(wd, "sub/d.json", "dataset", (".json",)) == wd / "sub/d.json"
    assert (wd / "sub").is_dir()
    assert output_path(wd, str(tmp_path / "x.json"), "dataset", (".json",)) == tmp_path / "x.json"
    (tmp_path / "f").write_text("")
    (wd / "d.json").mkdir()
    for text, words in [
        ("d.json", "is a directory"),
        ("d.yaml", "expected a .json file"),
        ("  ", "empty"),
        (str(tmp_path / "f" / "x.json"), "f is a file"),
    ]:
        with pytest.raises(InputError, match=words):
            output_path(wd, text, "dataset", (".json",))
    with pytest.raises(InputError, match="is a file"):
        ensure_dir(tmp_path / "f", "--workdir")


class Steps:
    """A StepRunner stand-in: records the commands the wizard would run."""

    def __init__(self) -> None:
        self.argv: list[list[str]] = []

    def run(self, argv: list[str], done: Any = None) -> None:
        self.argv.append(argv)

    def close(self) -> None:
        pass


@pytest.fixture
def server() -> Any:
    import viser

    s = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    yield s
    s.stop()


def test_the_wizard_writes_under_its_workdir_and_shows_mistakes_as_one_line(
    tmp_path: Path, server: Any
) -> None:
    wd = tmp_path / "wd"
    wizard = Wizard(server, N1, [], {"endpoint": None, "prefix": "beamrelay", "zenoh_config": None},
                    workdir=wd)  # fmt: skip
    wizard.steps = Steps()  # type: ignore[assignment]
    assert not wd.exists()  # created when first used
    wizard.cal.poses.value = 3
    wizard.collect()
    argv = wizard.steps.argv[-1]  # type: ignore[attr-defined]
    assert argv[argv.index("-o") + 1] == str(wd / "handeye_data.json") and wd.is_dir()
    wizard.calibrate()  # no dataset yet
    assert "run step 1 first" in wizard.cal.log.content
    (wd / "handeye_data.json").write_text("{}")
    wizard.calibrate()
    argv = wizard.steps.argv[-1]  # type: ignore[attr-defined]
    assert argv[argv.index("-o") + 1] == str(wd / "handeye.yaml")
    n = len(wizard.steps.argv)  # type: ignore[attr-defined]
    (tmp_path / "file").write_text("")
    for field, text, words in [
        (wizard.cal.output, str(tmp_path), "is a directory"),
        (wizard.cal.output, str(tmp_path / "file" / "c.yaml"), "file is a file"),
        (wizard.cal.dataset, "sub", "run step 1 first"),
    ]:
        field.value = text
        wizard.calibrate()
        assert words in wizard.cal.log.content and "\n" not in wizard.cal.log.content
        field.value = {"dataset": "calibration_data.json"}.get(field.label, "calibration.yaml")
    assert len(wizard.steps.argv) == n  # type: ignore[attr-defined]


def test_an_unusable_default_workdir_is_one_line_in_the_log(
    tmp_path: Path, server: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    (tmp_path / "data").write_text("")  # XDG_DATA_HOME is a file: the folder cannot be made
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "data"))
    wizard = Wizard(server, N1, [], {"endpoint": None, "prefix": "beamrelay", "zenoh_config": None})
    wizard.steps = Steps()  # type: ignore[assignment]
    assert wizard.workdir == tmp_path / "data/beamrelay/console"
    wizard.collect()
    assert "working directory: cannot create" in wizard.cal.log.content
    assert wizard.steps.argv == []  # type: ignore[attr-defined]


def test_up_passes_the_workdir_to_the_console() -> None:
    argv = child_commands(Path("/x/s.yaml"), ["arm0"], endpoint="e", console_port=8123,
                          console_workdir=Path("/w/c"))  # fmt: skip
    assert argv["console"][:4] == [sys.executable, "-m", "planner.cli", "console"]
    assert argv["console"][-2:] == ["--workdir", "/w/c"]
    assert "--workdir" not in child_commands(Path("/x/s.yaml"), ["arm0"], endpoint="e",
                                             console_port=8123)["console"]  # fmt: skip


def test_bad_workdir_options_exit_2_with_one_line(tmp_path: Path) -> None:
    (tmp_path / "f").write_text("")
    bad = str(tmp_path / "f")
    cli_run.assert_usage_error(cli_run.beamrelay("console", N1, "--workdir", bad), "--workdir",
                               "is a file")  # fmt: skip
    cli_run.assert_usage_error(
        cli_run.beamrelay("console", N1, "--workdir", f"{bad}/sub"), "--workdir", "cannot create"
    )
    cli_run.assert_usage_error(cli_run.beamrelay("up", N1, "--console-workdir", str(tmp_path)),
                               "needs --console")  # fmt: skip
    port = str(free_port())
    cli_run.assert_usage_error(
        cli_run.beamrelay("up", N1, "--console", "--console-port", port, "--console-workdir", bad),
        "--console-workdir",
        "is a file",
    )


def test_each_calibration_kind_has_its_own_default_files(tmp_path: Path, server: Any) -> None:
    """Choosing beam after hand-eye moves the default names to beam's (a beam calibration
    never overwrites the hand-eye dataset or file); a name the operator typed stays."""
    bus = {"endpoint": None, "prefix": "beamrelay", "zenoh_config": None}
    wizard = Wizard(server, N1, [], bus, workdir=tmp_path)
    cal = wizard.cal
    assert (cal.dataset.value, cal.output.value) == ("handeye_data.json", "handeye.yaml")
    cal.kind.value = "beam"
    wizard.kind_changed()
    assert (cal.dataset.value, cal.output.value) == ("beam_data.json", "beam.yaml")
    cal.output.value = "mine.yaml"
    cal.kind.value = "handeye"
    wizard.kind_changed()
    assert (cal.dataset.value, cal.output.value) == ("handeye_data.json", "mine.yaml")
