"""The command line a user meets: few commands, every option explained, the same default model as the
Python API, and ``slipsense --help`` without starting torch."""

from __future__ import annotations

import inspect
import subprocess
import sys

import typer.main

from slipsense import api
from slipsense.cli import app
from slipsense.cli import train as train_cli
from slipsense import config_tree

MAX_COMMANDS = 12


def _commands(group, prefix: str = ""):
    for name, cmd in group.commands.items():
        if hasattr(cmd, "commands"):  # a group of commands
            yield from _commands(cmd, f"{prefix}{name} ")
        else:
            yield f"{prefix}{name}", cmd


def test_at_most_twelve_commands():
    top = typer.main.get_command(app)
    assert len(top.commands) <= MAX_COMMANDS, sorted(top.commands)
    assert {"train", "evaluate", "watch", "calibrate", "label", "record", "export", "models"} <= set(top.commands)


def test_every_option_of_every_command_is_explained():
    missing = [
        f"slipsense {name} {param.opts[0]}"
        for name, cmd in _commands(typer.main.get_command(app))
        for param in cmd.params
        if param.param_type_name == "option" and param.name != "help" and not (param.help or "").strip()
    ]
    assert not missing, missing


def test_one_default_model_everywhere():
    from slipsense.training.settings import RunConfig
    from slipsense.training.grasps import GraspTrainConfig

    assert train_cli.DEFAULT_MODEL is config_tree.DEFAULT_MODEL == GraspTrainConfig().model == "motionnet"
    assert inspect.signature(api.fit).parameters["model"].default == config_tree.DEFAULT_MODEL
    assert RunConfig.from_tree({}).name == config_tree.DEFAULT_MODEL  # a tree that names none


def test_help_does_not_start_torch_and_importing_sets_nothing_process_wide():
    code = (
        "import os, sys, warnings; before = warnings.formatwarning; import slipsense.cli; "
        "assert 'torch' not in sys.modules, 'torch imported'; "
        "assert warnings.formatwarning is before, 'formatwarning replaced'; "
        "assert 'THP_MEM_ALLOC_ENABLE' not in os.environ or os.environ.get('KEEP') , 'environment changed'"
    )
    env = {k: v for k, v in __import__("os").environ.items() if k != "THP_MEM_ALLOC_ENABLE"}
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert proc.returncode == 0, proc.stderr
