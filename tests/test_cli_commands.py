"""The `t2m` dispatcher: every command registers, and running one imports only its own module."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from t2m.cli.main import COMMANDS, build_parser, main

REPO = Path(__file__).resolve().parents[1]


def test_every_command_registers_with_its_own_name() -> None:
    parser = build_parser(None)
    choices = parser._subparsers._group_actions[0].choices  # type: ignore[union-attr]
    assert set(choices) == set(COMMANDS)
    for name in COMMANDS:
        help_text = choices[name].format_help()
        assert help_text.startswith(f"usage: t2m {name}"), help_text[:80]


@pytest.mark.parametrize("command", ["serve", "generate", "edit", "motion"])
def test_runtime_commands_do_not_import_torch(command: str) -> None:
    code = (
        "import sys\n"
        "from t2m.cli.main import main\n"
        f"try:\n    main([{command!r}, '--help'])\nexcept SystemExit:\n    pass\n"
        "print('torch' in sys.modules)\n"
    )
    result = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, check=True)
    assert result.stdout.strip().splitlines()[-1] == "False"


def test_unknown_command_and_no_command_exit_non_zero(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as raised:
        main(["no-such-command"])
    assert raised.value.code == 2
    assert "invalid choice" in capsys.readouterr().err
    assert main([]) == 2


def test_embedded_bundles_are_named_by_their_folder(tmp_path, monkeypatch) -> None:
    from t2m.bundles import DEFAULT_BUNDLE, EMBEDDED_BUNDLES, resolve_bundle
    from t2m.service.serve_command import model_environment

    assert EMBEDDED_BUNDLES["default"] == DEFAULT_BUNDLE
    monkeypatch.chdir(tmp_path)
    env = model_environment([Path("default")])
    assert env == {"T2M_BUNDLE_PATH": str(DEFAULT_BUNDLE), "T2M_EXTRA_MODEL_DIRS": ""}
    (tmp_path / "default").mkdir()  # a directory of that name wins over the embedded bundle
    assert resolve_bundle("default") == Path("default")
    assert resolve_bundle("no-such-bundle") == Path("no-such-bundle")


@pytest.mark.parametrize(("command", "subject"), [("bench", "host-loop"), ("eval", "probes"),
                                                   ("bench", "hifigpt-vs-gpt"), ("eval", "diffusion-joins")])
def test_a_subject_runs_under_its_own_name(command: str, subject: str, capsys: pytest.CaptureFixture[str]) -> None:
    """`t2m bench SUBJECT` / `t2m eval SUBJECT`: the shared subjects and a family's own are reached by the CLI, and
    their usage says how they were called."""
    with pytest.raises(SystemExit) as raised:
        main([command, subject, "--help"])
    assert raised.value.code == 0
    assert capsys.readouterr().out.startswith(f"usage: t2m {command} {subject}")
    assert sys.argv[0] != f"t2m {command} {subject}"   # the program name is given back


def test_the_subjects_are_listed_in_the_commands_help() -> None:
    from t2m.cli.subjects import subjects

    for command in ("bench", "eval"):
        help_text = build_parser(command)._subparsers._group_actions[0].choices[command].format_help()  # type: ignore[union-attr]
        assert all(f"  {name} " in help_text for name in subjects(command)), help_text
