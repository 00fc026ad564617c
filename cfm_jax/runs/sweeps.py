"""Sweeps: a grid of configs run as one study, in-process or on a Ray cluster (:func:`sweep`).

A sweep is a grid of *cells* (:func:`grid`): every combination of the ``overrides`` (dotted
config paths, each with a list of values) times every controller loss. A cell is one
:func:`cfm_jax.train` call with the seeds as its vmap axis; cells that differ only in the
loss share one :class:`cfm_jax.learning.algorithm.Experiment`. Each finished cell is written at once
to ``out_dir/cells/<cell id>/``, so a re-run skips it. Backends, files and compilation:
docs/how-to/sweep.md. (The module is ``sweeps`` so that the function ``cfm_jax.sweep``
never shadows it.)
"""

from __future__ import annotations

import dataclasses
import hashlib
import importlib.util
import itertools
import json
import numbers
import os
import socket
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import pandas as pd

from cfm_jax import config as config_lib
from cfm_jax._files import write_atomic, write_text
from cfm_jax.analysis import plots, report

BACKENDS = ("local", "ray")
"""Backends of :func:`sweep`."""

RESERVED = {"loss": "losses", "seed": "seeds", "loop.seeds": "seeds"}
"""Config paths that are axes of the sweep itself, not overrides (path -> argument)."""


class SweepError(RuntimeError):
    """Some cells failed; the others' results are kept (on disk with an ``out_dir``: a re-run
    runs only the missing cells).

    Args:
      failures: ``{cell id: error text}`` (attribute ``failures``).
      result: a :class:`SweepResult` of the finished cells (attribute ``result``).
      total: the number of cells of the grid.

    Examples:
      >>> # not run: it runs a sweep (minutes)
      >>> try:  # doctest: +SKIP
      ...     result = cfm_jax.sweep(config, losses="all", out_dir="results/s")
      ... except cfm_jax.SweepError as error:
      ...     print(list(error.failures))  # the failed cells' ids
      ...     result = error.result  # the cells that finished
    """

    def __init__(self, failures: dict[str, str], result: SweepResult, total: int):
        self.failures = dict(failures)
        self.result = result
        where = (
            f"the finished cells are kept in {result.out_dir}/cells; run the same sweep again "
            "to run only the missing cells"
            if result.out_dir
            else "no out_dir, so nothing was written"
        )
        lines = [f"{len(failures)} of {total} cells failed ({where}):"]
        for cell_id, text in failures.items():
            lines.append(f"  {cell_id}: {text.strip().splitlines()[-1] if text.strip() else ''}")
        super().__init__("\n".join(lines))


@dataclasses.dataclass(frozen=True)
class Cell:
    """One cell of the grid: a full config (its loss, seeds and override values).

    Attributes:
      id: the cell id (:func:`cell_id`), its folder under ``out_dir/cells``.
      config: the cell's whole config.
      overrides: ``{dotted path: value}`` of this cell.

    Examples:
      >>> cell = grid(config_lib.Config(), losses="task", overrides={"task.kp": [50.0]})[0]
      >>> cell.loss, cell.overrides, cell.config.task.kp
      ('task', {'task.kp': 50.0}, 50.0)
    """

    id: str
    config: config_lib.Config
    overrides: dict[str, Any]

    @property
    def loss(self) -> str:
        """The cell's controller loss."""
        return self.config.loss


@dataclasses.dataclass
class CellOutput:
    """What running one cell gives back (:func:`run_cell`, or a custom ``runner``).

    Attributes:
      metrics: :attr:`cfm_jax.TrainResult.metrics` of the cell.
      baselines: :attr:`cfm_jax.TrainResult.baselines` of the cell.
      seconds: wall time of the cell.
      pid: the process that ran it.
      host: the machine that ran it.
      labels: the task's axis labels for figures (``tracking_label``, ``output_unit``).
      stopped: :attr:`cfm_jax.TrainResult.stopped`: seeds stopped by a non-finite training
        quantity (neither they nor a diverged rollout lose the cell).

    Examples:
      A custom runner does extra work around :func:`run_cell` and returns its output:

      >>> def runner(config, run_dir):
      ...     output = run_cell(config, run_dir)
      ...     print(config.loss, output.seconds)
      ...     return output
    """

    metrics: pd.DataFrame
    baselines: pd.DataFrame
    seconds: float
    pid: int
    host: str
    labels: dict = dataclasses.field(default_factory=dict)
    stopped: list = dataclasses.field(default_factory=list)


@dataclasses.dataclass
class SweepResult:
    """What :func:`sweep` returns.

    Attributes:
      metrics: the tidy table, one row per (cell, seed, iteration, target), in grid order
        whatever the backend: ``cell``, one column per override path (tuples as JSON text),
        then the columns of :attr:`cfm_jax.TrainResult.metrics`.
      baselines: oracle and PD-only tracking per target, per combination of override values.
      cells: one row per cell: ``cell``, the override columns, ``loss``, ``seconds``, ``pid``,
        ``host``, ``status`` (``ran`` or ``done before``).
      override_columns: the override paths, in the order given.
      out_dir: where the files are, or None.
      seconds: wall time of the sweep.

    Examples:
      >>> # not run: it trains every loss (minutes) and writes results/s
      >>> result = cfm_jax.sweep(config, losses="all", out_dir="results/s")  # doctest: +SKIP
      >>> print(result.markdown())  # the curves at the last iteration  # doctest: +SKIP
    """

    metrics: pd.DataFrame
    baselines: pd.DataFrame
    cells: pd.DataFrame
    override_columns: tuple[str, ...]
    out_dir: str | None
    seconds: float

    @property
    def group_columns(self) -> list[str]:
        """``loss`` and the override columns: what tells one curve from another."""
        return ["loss", *self.override_columns]

    def curves(self, columns: Sequence[str] | None = None) -> pd.DataFrame:
        """Mean and std over seeds per iteration and curve
        (:func:`cfm_jax.analysis.report.seed_curves`)."""
        return report.seed_curves(self.metrics, by=self.group_columns, columns=columns)

    def markdown(self, iteration: int | None = None) -> str:
        """The summary of ``summary.md`` at ``iteration`` (default: the last): the curves
        (:func:`cfm_jax.analysis.report.curves_markdown`), then per combination of override values
        the per-loss table with baselines and, with several losses, the paired differences of the
        joint (else the first) loss minus each other (docs/how-to/sweep.md)."""
        parts = [report.curves_markdown(self.curves(), self.group_columns, iteration)]
        parts += _summary_sections(
            self.metrics, self.baselines, list(self.override_columns), iteration
        )
        return "\n\n".join(parts)

    def plot(self, path: str | None = None, title: str = "", **labels):
        """The paper-style figure of the curves (:func:`cfm_jax.analysis.plots.plot_curves`;
        baselines when there are no overrides), also written to ``path`` if given; returns the
        ``Figure``."""
        baselines = self.baselines if not self.override_columns else None
        return plots.plot_curves(
            self.curves(), path, self.group_columns, baselines=baselines, title=title, **labels
        )


# ----- the grid ---------------------------------------------------------------------


def grid(
    base_config: config_lib.Config,
    seeds: int | Sequence[int] | None = None,
    losses: str | Sequence[str] | None = None,
    overrides: Mapping[str, Sequence[Any]] | None = None,
) -> list[Cell]:
    """The cells of a sweep: every combination of the override values (the first path varies
    slowest), and for each every loss.

    Args:
      base_config: the config every cell starts from.
      seeds: the number of seeds (``base_config.seed`` onwards), or consecutive seeds
        (``range(3, 6)``); None: ``base_config``'s.
      losses: a loss name, a list of them, or ``"all"``; None: ``base_config.loss``.
      overrides: ``{dotted path: [values]}``, e.g. ``{"controller.learning_rate": [1e-3,
        3e-4]}``; an int for a float field is that float (``100`` and ``100.0``: one cell).

    Raises:
      ConfigError: naming the argument or path, the bad value and what is allowed.

    Examples:
      >>> cells = grid(config_lib.Config(), seeds=3, losses=["joint", "task"],
      ...              overrides={"task.kp": [50, 100.0]})
      >>> [(c.loss, c.config.task.kp, c.config.loop.seeds) for c in cells]
      [('joint', 50.0, 3), ('task', 50.0, 3), ('joint', 100.0, 3), ('task', 100.0, 3)]
    """
    if not isinstance(base_config, config_lib.Config):
        config_lib.fail("base_config", base_config, "a cfm_jax.Config")
    first, count = _seeds(base_config, seeds)
    names = _losses(base_config, losses)
    paths, value_lists = _overrides(base_config, overrides)
    base = config_lib.to_dict(base_config)
    base["seed"] = first
    base["loop"] = {**base["loop"], "seeds": count}
    cells = []
    for values in itertools.product(*value_lists):
        changed = json.loads(json.dumps(base))
        for path, value in zip(paths, values, strict=True):
            _set_path(changed, path, value)
        for loss in names:
            changed["loss"] = loss
            config = config_lib.from_dict(_tuples(changed))
            cells.append(Cell(cell_id(config), config, dict(zip(paths, values, strict=True))))
    return cells


def cell_id(config: config_lib.Config) -> str:
    """The id of ``config``'s cell: ``<loss>-<12 hex digits of the SHA-256 of its JSON>``.

    Args:
      config: a cell's whole config.

    Examples:
      >>> cell_id(config_lib.Config(loss="task")).startswith("task-")
      True
    """
    text = json.dumps(config_lib.to_dict(config), sort_keys=True)
    return f"{config.loss}-{hashlib.sha256(text.encode()).hexdigest()[:12]}"


def _seeds(base: config_lib.Config, seeds) -> tuple[int, int]:
    if seeds is None:
        return base.seed, base.loop.seeds
    if isinstance(seeds, numbers.Integral) and not isinstance(seeds, bool):
        if seeds <= 0:
            config_lib.fail("seeds", seeds, "a positive number of seeds or consecutive seeds")
        return base.seed, int(seeds)
    try:
        values = [int(s) for s in seeds]
    except (TypeError, ValueError):
        config_lib.fail("seeds", seeds, "a positive number of seeds or consecutive seeds")
    if (
        not values
        or values[0] < 0
        or values != list(range(values[0], values[0] + len(values)))
        or any(isinstance(s, bool) or int(s) != s for s in seeds)
    ):
        config_lib.fail(
            "seeds",
            seeds,
            "consecutive integers >= 0 in increasing order (they are one vmap axis), "
            "e.g. range(3) or [3, 4, 5]",
        )
    return values[0], len(values)


def _losses(base: config_lib.Config, losses) -> list[str]:
    return [base.loss] if losses is None else list(config_lib.loss_names(losses))


def _overrides(base: config_lib.Config, overrides) -> tuple[list[str], list[list[Any]]]:
    if overrides is None:
        return [], []
    if not isinstance(overrides, Mapping):
        config_lib.fail("overrides", overrides, "a dict {dotted config path: [values]}")
    tree = config_lib.to_dict(base)
    paths, value_lists = [], []
    for path, values in overrides.items():
        field = f"overrides[{path!r}]"
        if not isinstance(path, str):
            config_lib.fail("overrides", path, "dotted config paths (strings) as keys")
        if path in RESERVED:
            config_lib.fail(
                field, values, f"{path} is an axis of the sweep: use sweep's {RESERVED[path]}="
            )
        if path == "task.name":  # an override keeps the base's sections: another task's
            config_lib.fail(
                field,
                values,
                "one sweep per task: a task brings its own defaults (its default_config), "
                "which an override of task.name would not take; sweep each task from "
                "cfm_jax.for_task(name) (the CLI: cfm-jax sweep --task NAME)",
            )
        current = _get_path(tree, path)
        if isinstance(values, str | bytes) or not isinstance(values, Sequence) or not values:
            config_lib.fail(field, values, "a non-empty list of values, e.g. [1e-3, 3e-4]")
        normal = [_normalise(current, v) for v in values]
        texts = [json.dumps(v) for v in normal]
        if len(set(texts)) != len(texts):
            config_lib.fail(field, values, "distinct values (a value appears twice)")
        paths.append(path)
        value_lists.append(normal)
    return paths, value_lists


def _get_path(tree: dict, path: str):
    node = tree
    parts = path.split(".")
    for depth, part in enumerate(parts):
        here = ".".join(parts[:depth]) or "the config"
        if not isinstance(node, dict) or part not in node:
            known = sorted(node) if isinstance(node, dict) else []
            if node is None and here == "forward.options":  # a kind without options
                known = f"none: the base's forward.kind={tree['forward']['kind']!r} takes none"
            config_lib.fail(
                f"overrides[{path!r}]",
                path,
                f"a dotted path to a config field; the fields of {here} are {known}",
            )
        node = node[part]
    if isinstance(node, dict):
        config_lib.fail(
            f"overrides[{path!r}]",
            path,
            f"a path to a single field, not a section; its fields are {sorted(node)}",
        )
    return node


def _set_path(tree: dict, path: str, value) -> None:
    *parents, last = path.split(".")
    node = tree
    for part in parents:
        node = node[part]
    node[last] = value


def _normalise(current, value):
    """Lists to tuples (configs hold tuples); an int for a float field to a float."""
    value = _tuples(value)
    if isinstance(current, float) and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    return value


def _tuples(value):
    if isinstance(value, dict):
        return {k: _tuples(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return tuple(_tuples(v) for v in value)
    return value


def _plain(overrides: dict) -> dict:
    """Override values as JSON data (tuples become lists when dumped)."""
    return {path: _tuples(value) for path, value in overrides.items()}


def _column_value(value):
    """An override value as a table entry: scalars as they are, tuples as JSON text."""
    return json.dumps(value) if isinstance(value, tuple | list) else value


# ----- running one cell ---------------------------------------------------------------


def run_cell(
    config: config_lib.Config, run_dir: str | None = None, progress: bool = False
) -> CellOutput:
    """Run one cell: :func:`cfm_jax.train` on ``config`` (what :func:`run_cells` does for one).

    A ``run_dir`` holding checkpoints of an interrupted attempt resumes from the newest valid
    one (bit for bit the uninterrupted run), else the cell starts afresh.

    Args:
      config: the cell's config (its seeds are the vmap axis).
      run_dir: train's output directory for this cell, or None (nothing written).
      progress: show train's progress bar.

    Examples:
      >>> # not run: it trains (minutes)
      >>> output = run_cell(config_lib.Config(robot="two_link_arm"))  # doctest: +SKIP
    """
    import warnings

    from cfm_jax.runs import checkpoint as ckpt_lib
    from cfm_jax.runs import training

    start = time.perf_counter()
    experiment = training.Experiment.shared(config)
    resume = run_dir if _resumable(run_dir, config) else None
    try:
        result = training.train(
            config, progress=progress, out_dir=run_dir, experiment=experiment, resume=resume
        )
    except ckpt_lib.CheckpointError as error:
        if resume is None:
            raise
        warnings.warn(f"{run_dir}: {error}; running the cell from the start", stacklevel=2)
        import shutil

        shutil.rmtree(run_dir)
        result = training.train(config, progress=progress, out_dir=run_dir, experiment=experiment)
    return _cell_output(experiment, result, time.perf_counter() - start)


def run_cells(
    configs: Sequence[config_lib.Config],
    run_dirs: Sequence[str | None],
    progress: bool = False,
) -> list[CellOutput]:
    """Run cells that differ only in the loss together: :func:`cfm_jax.train` with ``losses``
    (one babbling and initial fit of f per seed; each loss's numbers are those of its cell
    run alone, bit for bit). What :func:`sweep` runs when no ``runner`` is given.

    Each cell's ``run_dir`` holding checkpoints of an interrupted attempt resumes from its
    newest valid one; a corrupt checkpoint restarts the cells from the beginning (warned).
    Each cell's ``seconds`` is its share of the cells' wall time.

    Args:
      configs: the cells' configs; they differ in ``loss`` only.
      run_dirs: train's output folder of each cell, or None (nothing written).
      progress: show train's progress bar.

    Raises:
      ValueError: the configs differ in more than the loss, or a loss repeats.

    Examples:
      >>> # not run: it trains two losses (minutes)
      >>> base = config_lib.Config(robot="two_link_arm")
      >>> joint, task = run_cells([base, base.replace(loss="task")], [None, None])  # doctest: +SKIP
    """
    import warnings

    from cfm_jax.runs import checkpoint as ckpt_lib
    from cfm_jax.runs import training

    if len(configs) == 1:
        return [run_cell(configs[0], run_dirs[0], progress)]
    first = configs[0]
    others = [c for c in configs if c.replace(loss=first.loss) != first]
    if others:
        raise ValueError(f"run_cells: the configs differ in more than the loss: {others[0]}")
    start = time.perf_counter()
    experiment = training.Experiment.shared(first)
    names = [c.loss for c in configs]
    out = dict(zip(names, run_dirs, strict=True))
    resume = {name: folder for name, folder in out.items() if _resumable(folder, first)}
    try:
        result = training.train(first, progress=progress, out_dir=out, experiment=experiment,
                                resume=resume or None, losses=names)  # fmt: skip
    except ckpt_lib.CheckpointError as error:
        if not resume:
            raise
        warnings.warn(f"{error}; running the cells {names} from the start", stacklevel=2)
        import shutil

        for folder in resume.values():
            shutil.rmtree(folder)
        result = training.train(first, progress=progress, out_dir=out, experiment=experiment,
                                losses=names)  # fmt: skip
    seconds = (time.perf_counter() - start) / len(configs)
    outputs = []
    for name in names:
        own = result.of(name)
        outputs.append(_cell_output(experiment, own, seconds))
    return outputs


def _resumable(run_dir: str | None, config: config_lib.Config) -> bool:
    """Whether ``run_dir`` holds an interrupted attempt to resume (checkpoints and config)."""
    if run_dir is None or config.loop.checkpoint_every <= 0:
        return False
    return os.path.isdir(os.path.join(run_dir, "checkpoints")) and os.path.isfile(
        os.path.join(run_dir, "config.json")
    )


def _cell_output(experiment, result, seconds: float) -> CellOutput:
    task = experiment.task
    return CellOutput(
        metrics=result.metrics,
        baselines=result.baselines,
        seconds=seconds,
        pid=os.getpid(),
        host=socket.gethostname(),
        labels={
            "tracking_label": f"{task.tracking_name} ({task.tracking_unit}$^2$)",
            "output_unit": task.output_unit,
        },
        stopped=list(result.stopped),
    )


def _ray_task(runner, configs: list[dict], run_dirs: list) -> list[CellOutput]:
    """The body of a Ray task: cells that differ only in the loss (:func:`run_cells`), or one
    cell of a custom ``runner`` (the configs travel as plain JSON data)."""
    configs = [config_lib.from_dict(_tuples(config)) for config in configs]
    if runner is None:
        return run_cells(configs, run_dirs)
    return [runner(configs[0], run_dirs[0])]


# ----- the sweep ----------------------------------------------------------------------


def sweep(
    base_config: config_lib.Config,
    seeds: int | Sequence[int] | None = None,
    losses: str | Sequence[str] | None = None,
    overrides: Mapping[str, Sequence[Any]] | None = None,
    out_dir: str | None = None,
    backend: str = "local",
    address: str | None = None,
    max_retries: int = 3,
    cpus_per_cell: float = 1.0,
    checkpoints: bool = True,
    progress: bool = True,
    runner: Callable[[config_lib.Config, str | None], CellOutput] | None = None,
) -> SweepResult:
    """Run a grid of cells (:func:`grid`) and gather one tidy table (docs/how-to/sweep.md).

    Args:
      base_config: the config every cell starts from (see :func:`grid`).
      seeds: the number of seeds, or consecutive seeds (see :func:`grid`).
      losses: a loss, a list of losses or ``"all"`` (see :func:`grid`).
      overrides: ``{dotted config path: [values]}``, the further grid axes (see :func:`grid`).
      out_dir: where results go (created): each cell in ``out_dir/cells/<cell id>/`` as it
        finishes (a re-run skips it), then the tables, ``summary.md`` and ``curves.png``;
        None: nothing is written.
      backend: ``"local"`` (this process, one cell after another) or ``"ray"``.
      address: ray only: an existing cluster (``"host:port"`` or ``"auto"``); None: this
        process's Ray instance, else a local one (all cores). A connection it opens, it closes.
      max_retries: ray only: retries of a cell whose worker process dies (an exception is
        reported, not retried).
      cpus_per_cell: ray only: the CPUs a task reserves (sets how many run at once); a task
        trains the cells that differ only in the loss (one cell with a custom ``runner``).
      checkpoints: give each cell the run directory ``out_dir/cells/<id>/run`` (on the
        worker's machine), so an interrupted cell resumes from its last checkpoint.
      progress: progress bars (local) and a line per finished cell.
      runner: ``runner(config, run_dir) -> CellOutput`` runs one cell (picklable for Ray);
        default: :func:`run_cells`, the cells that differ only in the loss trained together
        (the loss a batch axis: one compile, one babbling per seed, the same numbers).

    Returns:
      A :class:`SweepResult`.

    Raises:
      ConfigError: a bad argument (named, with what is allowed).
      SweepError: some cells failed; the others are kept (``error.result``).

    Examples:
      >>> config = cfm_jax.for_task("inverse_dynamics", robot="iiwa14")
      >>> # not run: it needs ray and trains every loss (minutes)
      >>> result = cfm_jax.sweep(  # doctest: +SKIP
      ...     config, seeds=3, losses="all", overrides={"task.kp": [50.0, 100.0]},
      ...     out_dir="results/kp", backend="ray")
    """
    start = time.perf_counter()
    cells = grid(base_config, seeds, losses, overrides)
    if backend not in BACKENDS:
        config_lib.fail("backend", backend, f"one of {BACKENDS}")
    if backend == "local" and address is not None:
        config_lib.fail("address", address, "None with backend='local' (ray only)")
    if isinstance(max_retries, bool) or not isinstance(max_retries, int) or max_retries < 0:
        config_lib.fail("max_retries", max_retries, "an integer >= 0")
    if isinstance(cpus_per_cell, bool) or not isinstance(cpus_per_cell, int | float):
        config_lib.fail("cpus_per_cell", cpus_per_cell, "a number > 0")
    if cpus_per_cell <= 0:
        config_lib.fail("cpus_per_cell", cpus_per_cell, "a number > 0")
    paths = tuple(cells[0].overrides)
    outputs: dict[str, CellOutput] = {}
    done_before: set[str] = set()
    if out_dir is not None:
        os.makedirs(os.path.join(out_dir, "cells"), exist_ok=True)
        for cell in cells:
            output = _load_cell(out_dir, cell)
            if output is not None:
                outputs[cell.id] = output
                done_before.add(cell.id)
    todo = [cell for cell in cells if cell.id not in outputs]
    failures: dict[str, str] = {}
    say = _reporter(progress, len(cells), len(done_before))

    def finished(cell: Cell, output: CellOutput) -> None:
        outputs[cell.id] = output
        if out_dir is not None:
            _write_cell(out_dir, cell, output)
        say(cell, f"done in {output.seconds:.0f} s")

    def failed(cell: Cell, text: str) -> None:
        failures[cell.id] = text
        say(cell, "FAILED: " + (text.strip().splitlines() or [""])[-1])

    def run_dir(cell: Cell) -> str | None:
        if out_dir is None or not checkpoints:
            return None
        return os.path.abspath(os.path.join(out_dir, "cells", cell.id, "run"))

    # The default runner trains the cells that differ only in the loss together (run_cells);
    # a custom runner gets one cell at a time.
    units = _by_structure(todo) if runner is None else [[cell] for cell in todo]
    if units and backend == "local":
        for unit in units:
            try:
                if runner is None:
                    got = run_cells([c.config for c in unit], [run_dir(c) for c in unit], progress)
                else:
                    got = [runner(unit[0].config, run_dir(unit[0]))]
            except Exception as error:  # reported in SweepError; the other cells go on
                for cell in unit:
                    failed(cell, f"{type(error).__name__}: {error}")
            else:
                for cell, output in zip(unit, got, strict=True):
                    finished(cell, output)
    elif units:
        _run_ray(units, runner, run_dir, address, max_retries, cpus_per_cell, finished, failed)
    result = _collect(cells, outputs, done_before, paths, out_dir, time.perf_counter() - start)
    if failures:
        raise SweepError(failures, result, len(cells))
    if out_dir is not None:
        _write_tables(out_dir, result, base_config, cells, outputs[cells[0].id].labels)
    return result


def _run_ray(units, runner, run_dir, address, max_retries, cpus_per_cell, finished, failed):
    try:
        import ray
    except ImportError:
        config_lib.fail(
            "backend", "ray", "'local' here: Ray is not installed (pip install 'cfm_jax[ray]')"
        )
    started = False
    if ray.is_initialized() and address not in (None, "auto"):
        current = ray.get_runtime_context().gcs_address
        if address != current:
            config_lib.fail(
                "address",
                address,
                f"None or {current!r}: this process is already connected to the Ray cluster "
                f"at {current} (ray.shutdown() first to use another)",
            )
    if not ray.is_initialized():
        if address is None:
            ray.init(include_dashboard=False)
        else:
            ray.init(address=address)
        started = True
    try:
        task = ray.remote(_ray_task).options(
            max_retries=max_retries, retry_exceptions=False, num_cpus=cpus_per_cell
        )
        refs = {
            task.remote(
                runner,
                [config_lib.to_dict(cell.config) for cell in unit],
                [run_dir(cell) for cell in unit],
            ): unit
            for unit in units
        }
        pending = list(refs)
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            for ref in ready:
                unit = refs[ref]
                try:
                    got = ray.get(ref)
                except ray.exceptions.RayError as error:
                    cause = getattr(error, "cause", None)
                    for cell in unit:
                        if isinstance(cause, BaseException):
                            failed(cell, f"{type(cause).__name__}: {cause}")
                        else:
                            failed(cell, f"{type(error).__name__}: {error}")
                else:
                    for cell, output in zip(unit, got, strict=True):
                        finished(cell, output)
    finally:
        if started:
            ray.shutdown()


def _by_structure(cells: list[Cell]) -> list[list[Cell]]:
    """``cells`` grouped by everything but the loss (grid order kept): the cells one
    :func:`run_cells` trains together."""
    groups: dict[str, list[Cell]] = {}
    for cell in cells:
        key = json.dumps(config_lib.to_dict(cell.config.replace(loss="joint")), sort_keys=True)
        groups.setdefault(key, []).append(cell)
    return list(groups.values())


def _reporter(progress: bool, total: int, done_before: int):
    count = [done_before]
    if progress and done_before:
        print(f"sweep: {done_before} of {total} cells finished before, skipped", flush=True)

    def say(cell: Cell, text: str) -> None:
        count[0] += 1
        if progress:
            print(f"sweep: cell {count[0]}/{total} {cell.id} {text}", flush=True)

    return say


# ----- files --------------------------------------------------------------------------


def _write_cell(out_dir: str, cell: Cell, output: CellOutput) -> None:
    """A cell's files, each written whole and renamed; ``metrics.csv`` last marks it finished."""
    directory = os.path.join(out_dir, "cells", cell.id)
    os.makedirs(directory, exist_ok=True)
    config_text = json.dumps(report.config_record(cell.config), indent=2)
    write_text(os.path.join(directory, "config.json"), config_text)
    info = {
        "cell": cell.id,
        "loss": cell.loss,
        "overrides": _plain(cell.overrides),
        "seconds": output.seconds,
        "pid": output.pid,
        "host": output.host,
        "labels": output.labels,
        "stopped": output.stopped,
    }
    write_text(os.path.join(directory, "cell.json"), json.dumps(info, indent=2))
    write_atomic(
        os.path.join(directory, "baselines.csv"),
        lambda tmp: output.baselines.to_csv(tmp, index=False),
    )
    write_atomic(
        os.path.join(directory, "metrics.csv"), lambda tmp: output.metrics.to_csv(tmp, index=False)
    )


def _read_csv(path: str) -> pd.DataFrame:
    # pandas writes floats as their shortest repr and reads them back exactly (tested)
    return pd.read_csv(path)


def _load_cell(out_dir: str, cell: Cell) -> CellOutput | None:
    """The saved output of a finished cell of this exact config, else None."""
    directory = os.path.join(out_dir, "cells", cell.id)
    try:
        with open(os.path.join(directory, "config.json")) as f:
            if json.load(f) != report.config_record(cell.config):
                return None
        with open(os.path.join(directory, "cell.json")) as f:
            info = json.load(f)
        metrics = _read_csv(os.path.join(directory, "metrics.csv"))
        baselines = _read_csv(os.path.join(directory, "baselines.csv"))
        return CellOutput(
            metrics,
            baselines,
            info["seconds"],
            info["pid"],
            info["host"],
            info.get("labels", {}),
            info.get("stopped", []),
        )
    except (FileNotFoundError, KeyError, json.JSONDecodeError, pd.errors.EmptyDataError):
        return None


def _collect(cells, outputs, done_before, paths, out_dir, seconds) -> SweepResult:
    frames, base_frames, rows, seen = [], [], [], set()
    for cell in cells:
        output = outputs.get(cell.id)
        if output is None:
            continue
        columns = {"cell": cell.id}
        columns.update({p: _column_value(cell.overrides[p]) for p in paths})
        metrics = output.metrics.copy()
        for position, (name, value) in enumerate(columns.items()):
            metrics.insert(position, name, [value] * len(metrics))
        frames.append(metrics)
        combination = json.dumps([cell.overrides[p] for p in paths])
        if combination not in seen:
            seen.add(combination)
            baselines = output.baselines.copy()
            for position, path in enumerate(paths):
                value = _column_value(cell.overrides[path])
                baselines.insert(position, path, [value] * len(baselines))
            base_frames.append(baselines)
        rows.append(
            {
                **columns,
                "loss": cell.loss,
                "seconds": output.seconds,
                "pid": output.pid,
                "host": output.host,
                "status": "done before" if cell.id in done_before else "ran",
            }
        )
    return SweepResult(
        metrics=pd.concat(frames, ignore_index=True) if frames else pd.DataFrame(),
        baselines=pd.concat(base_frames, ignore_index=True) if base_frames else pd.DataFrame(),
        cells=pd.DataFrame(rows),
        override_columns=tuple(paths),
        out_dir=out_dir,
        seconds=seconds,
    )


def _summary_sections(metrics, baselines, paths, iteration) -> list[str]:
    """:meth:`SweepResult.markdown`'s sections after the curves, per override combination."""
    if metrics.empty or "tracking_mse" not in metrics or "loss" not in metrics:
        return []
    groups = metrics.groupby(paths, sort=False, dropna=False) if paths else [((), metrics)]
    sections = []
    for _, frame in groups:
        values = {path: frame[path].iloc[0] for path in paths}
        where = "".join(f", {path}={value}" for path, value in values.items())
        base = None
        if "baseline" in baselines and "tracking_mse" in baselines:
            keep = pd.Series(True, index=baselines.index)
            for path, value in values.items():  # text keys: NaN, None and tuples compare
                keep &= baselines[path].map(str) == str(value) if path in baselines else False
            base = baselines[keep] if keep.any() else None
        if iteration is not None and not (frame["iteration"] == iteration).any():
            continue
        table = report.summary(frame, base, iteration=iteration)
        at = "the last iteration" if iteration is None else f"iteration {iteration}"
        sections.append(
            f"tracking_mse per loss at {at}{where}: mean and std over seeds x targets, "
            "and the mean's confidence interval over seeds\n\n" + report.markdown(table)
        )
        if frame["loss"].nunique() > 1:
            paired = report.paired_table(frame, reference=None, iteration=iteration)
            sections.append(report.paired_markdown(paired))
    return sections


def parquet_available() -> bool:
    """Whether pyarrow is installed (the ``parquet`` extra): then a sweep also writes its
    table as ``metrics.parquet``, beside ``metrics.csv``.

    Examples:
      >>> isinstance(parquet_available(), bool)
      True
    """
    return importlib.util.find_spec("pyarrow") is not None


def _write_tables(out_dir: str, result: SweepResult, base_config, cells, labels) -> None:
    """The sweep's files (tables, grid, summary, figure), each written whole and renamed."""
    write_atomic(
        os.path.join(out_dir, "metrics.csv"), lambda tmp: result.metrics.to_csv(tmp, index=False)
    )
    if parquet_available():
        write_atomic(
            os.path.join(out_dir, "metrics.parquet"),
            lambda tmp: result.metrics.to_parquet(tmp, index=False, engine="pyarrow"),
        )
    write_atomic(
        os.path.join(out_dir, "baselines.csv"),
        lambda tmp: result.baselines.to_csv(tmp, index=False),
    )
    write_atomic(
        os.path.join(out_dir, "cells.csv"), lambda tmp: result.cells.to_csv(tmp, index=False)
    )
    description = {
        "base_config": report.config_record(base_config),
        "cells": [{"cell": c.id, "loss": c.loss, "overrides": _plain(c.overrides)} for c in cells],
    }
    write_text(os.path.join(out_dir, "sweep.json"), json.dumps(description, indent=2))
    protocol = report.protocol(base_config)
    overridden = ("loop.babbling", "forward.kind", "forward.options")
    if any(path.startswith(overridden) for path in result.override_columns):
        protocol += " (the base; the cells override it, see the columns)"
    write_text(os.path.join(out_dir, "summary.md"), protocol + "\n\n" + result.markdown() + "\n")
    config = cells[0].config
    result.plot(
        os.path.join(out_dir, "curves.png"),
        title=f"{config.robot} {config.task.name}",
        **labels,
    )
