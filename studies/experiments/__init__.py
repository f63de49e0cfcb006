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

Modules: :mod:`~studies.experiments.settings` (:class:`Settings`: full, quick and overrides),
:mod:`~studies.experiments.source` (:class:`DataSource`, held-out objects),
:mod:`~studies.experiments.report` (:class:`Report`, machine information),
:mod:`~studies.experiments.training` (train, score, time); one module per experiment
(``params``, ``video_compare``, ``frames``, ``noise``, ``stnet``, ``horizon``, ``all_models``); and
:mod:`~studies.experiments.results` (studies/docs/results.md). The commands are in
:mod:`studies.experiments.commands`. Beside them: :mod:`~studies.experiments.resnet_weights` (the
3D ResNet's weights from a file, for ``video-compare --resnet-weights``) and
:mod:`~studies.experiments.vivit_reference` (vit-pytorch's ViViT weights in slipsense's, for
``bench/bench_vivit.py`` and the test that the two compute the same function).
"""
