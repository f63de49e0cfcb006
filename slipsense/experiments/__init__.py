"""The experiments of the two studies (and two beyond them), each one command with a report folder.

Every experiment writes into its folder ``OUT``:

* ``<name>.csv``  the result table (one row per model / condition), with a ``setting`` column;
* ``<name>.md``   the same table in Markdown, headed by the setting it ran under;
* ``<name>.png``  the figure;
* ``config.json`` (written last: its presence means the folder is complete) the exact resolved
  configuration (seeds, data, clip settings, every model's config and training settings), the
  command line, the machine (platform, CPU count, torch version, device) and timings;
* ``runs/<label>/`` the training runs behind it (``metrics.csv``, ``curves.png``, checkpoints);
  ``--resume`` continues them after an interruption.

Modules: :mod:`~slipsense.experiments.settings` (:class:`Settings`: full, quick and overrides),
:mod:`~slipsense.experiments.source` (:class:`DataSource`, held-out objects),
:mod:`~slipsense.experiments.report` (:class:`Report`, machine information),
:mod:`~slipsense.experiments.training` (train, score, time); one module per experiment
(``params``, ``video_compare``, ``frames``, ``noise``, ``stnet``, ``horizon``, ``all_models``); and
:mod:`~slipsense.experiments.results` (docs/results.md). The commands are in
:mod:`slipsense.cli.experiments`.
"""

from slipsense.experiments.settings import EXPERIMENTS, FULL_PATCH, FULL_SIZE, QUICK_PATCH, QUICK_SIZE, TITLES, Settings
from slipsense.experiments.source import FPS, DataSource, clip_spec, default_overrides, held_out_objects, object_split
from slipsense.experiments.report import (
    Report,
    cpu_description,
    cpu_model,
    csv_text,
    machine_info,
    machine_line,
    markdown_table,
)
from slipsense.experiments.training import inference_rate, score, train_model, train_seconds
from slipsense.experiments.params import run_params
from slipsense.experiments.video_compare import run_video_compare
from slipsense.experiments.frames import DEFAULT_FRAMES_LIST, run_frames
from slipsense.experiments.noise import DEFAULT_NOISE_STDS, run_noise
from slipsense.experiments.stnet import QUICK_SIM_SEQUENCES, SIM_SEQUENCES, run_stnet, simulated_markers
from slipsense.experiments.horizon import DEFAULT_HORIZONS, run_horizon
from slipsense.experiments.all_models import match_windows, run_all_models
from slipsense.experiments.results import BENCH_SCRIPTS, REQUIREMENTS, collect_results, command_lines, find_reports
from slipsense.experiments.results import _data_line  # noqa: F401  (tests reach it as slipsense.experiments._data_line)

__all__ = [
    "BENCH_SCRIPTS",
    "DEFAULT_FRAMES_LIST",
    "DEFAULT_HORIZONS",
    "DEFAULT_NOISE_STDS",
    "EXPERIMENTS",
    "FPS",
    "FULL_PATCH",
    "FULL_SIZE",
    "QUICK_PATCH",
    "QUICK_SIM_SEQUENCES",
    "QUICK_SIZE",
    "REQUIREMENTS",
    "SIM_SEQUENCES",
    "TITLES",
    "DataSource",
    "Report",
    "Settings",
    "clip_spec",
    "collect_results",
    "command_lines",
    "cpu_description",
    "cpu_model",
    "csv_text",
    "default_overrides",
    "find_reports",
    "held_out_objects",
    "inference_rate",
    "machine_info",
    "machine_line",
    "markdown_table",
    "match_windows",
    "object_split",
    "run_all_models",
    "run_frames",
    "run_horizon",
    "run_noise",
    "run_params",
    "run_stnet",
    "run_video_compare",
    "score",
    "simulated_markers",
    "train_model",
    "train_seconds",
]
