"""What every entry point does on the console: one summary line at the end, one line for a user's mistake.

    @cli.entry_point("track", metric="mota", files="output_dir")
    def main(cfg: DictConfig) -> float:
        return run(cfg)["mota"]

`entry_point` stands in for `@hydra.main` (the configs of conf/). After the task it prints

    spacetrack track: mota 0.734 | files: outputs/track/... | MLflow: http://127.0.0.1:5000/#/experiments/2/runs/...

(the URL on the server `make ui` serves; in a multirun the multirun's parent prints one line for all).

A user error is what a user can cause and fix without reading our code:
- `UserError`, for checks at the edges that want no other class;
- a Hydra error about the command line or the config files (a misspelt key, an unknown option of a
  group, a bad override), or an instantiation that fails on one of those;
- a `ValueError` or `OSError` (`FileNotFoundError`, ...) that spacetrack's own code raises: the checks
  at the edges (a fold out of range, a missing or truncated video, missing weights, a malformed
  detection file, a stale cache with `cache.rebuild=false`) raise those with a message that names the
  file, the value and what was expected.
It comes out as `spacetrack: error: <message>` on one line, exit status 2. The same exceptions raised
inside a library (numpy, torch, ...), and every other exception, are internal errors and keep their
traceback; `--verbose` or `HYDRA_FULL_ERROR=1` shows the traceback of user errors too.
"""

from __future__ import annotations

import functools
import os
import sys
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.errors import CompactHydraException, InstantiationException
from hydra.types import RunMode
from omegaconf import DictConfig, OmegaConf

from spacetrack import mlflow_ui
from spacetrack.config import CONF_DIR

PACKAGE_DIR = Path(__file__).resolve().parent
VERBOSE_FLAG = "--verbose"
FULL_ERROR_ENV = "HYDRA_FULL_ERROR"
VERBOSE_ENV = "SPACETRACK_VERBOSE"  # set by report_errors for the task (and a launcher's workers)
USER_ERROR_STATUS = 2
NOT_LOGGED = "off (logger=none)"


class UserError(Exception):
    """A mistake in what the user asked for; its message says what was given and what was expected."""


def _raised_here(exc: BaseException) -> bool:
    """Whether the innermost frame of `exc`'s traceback is spacetrack's own code."""
    tb = exc.__traceback__
    if tb is None:
        return False
    while tb.tb_next is not None:
        tb = tb.tb_next
    return Path(tb.tb_frame.f_code.co_filename).resolve().is_relative_to(PACKAGE_DIR)


def user_error_message(exc: BaseException) -> str | None:
    """The one-line message of a user error (see the module docstring), or None for an internal error."""
    if isinstance(exc, InstantiationException):
        cause = exc.__cause__
        return _one_line(str(exc)) if cause is not None and user_error_message(cause) else None
    if isinstance(exc, CompactHydraException):  # composition, a missing config, an override's syntax
        text = str(exc)
        if exc.__cause__ is not None:  # OmegaConf's reason; its first line, without the key dump below it
            text += " (" + str(exc.__cause__).splitlines()[0] + ")"
        return _one_line(text)
    if isinstance(exc, UserError) or (isinstance(exc, (ValueError, OSError)) and _raised_here(exc)):
        return _one_line(str(exc)) or type(exc).__name__
    return None


def _one_line(text: str) -> str:
    return " ".join(part.strip() for part in text.splitlines() if part.strip())


@contextmanager
def user_errors_exit() -> Iterator[None]:
    """Inside the block a user error becomes `spacetrack: error: <message>` on stderr and exit status 2,
    unless `--verbose` or `HYDRA_FULL_ERROR=1` asked for tracebacks; every other error passes through."""
    try:
        yield
    except Exception as exc:
        message = None if os.environ.get(VERBOSE_ENV) == "1" else user_error_message(exc)
        if message is None:
            raise
        print(f"spacetrack: error: {message}", file=sys.stderr, flush=True)
        raise SystemExit(USER_ERROR_STATUS) from None


def report_errors(main: Callable[[], Any]) -> Any:
    """Call `main()` (a command-line entry point) with user errors as one line (`user_errors_exit`).

    Strips `--verbose` from `sys.argv` first. Hydra is told to re-raise what it meets (a config error
    before the task, an internal error in it), so that it reaches here with its traceback intact.
    """
    verbose = VERBOSE_FLAG in sys.argv[1:] or os.environ.get(FULL_ERROR_ENV, "") not in ("", "0")
    sys.argv[1:] = [arg for arg in sys.argv[1:] if arg != VERBOSE_FLAG]
    saved = {name: os.environ.get(name) for name in (FULL_ERROR_ENV, VERBOSE_ENV)}
    os.environ[FULL_ERROR_ENV], os.environ[VERBOSE_ENV] = "1", "1" if verbose else "0"
    try:
        with user_errors_exit():
            return main()
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


def format_metrics(value: Any, metric: str | None = None) -> str:
    """`mota 0.734` for a number named `metric`, `a 1, b 2` for a mapping, '' for None."""
    if value is None:
        return ""
    if isinstance(value, Mapping):
        return ", ".join(
            f"{k} {v:.4g}" if isinstance(v, (int, float)) else f"{k} {v}" for k, v in value.items()
        )
    return f"{metric or 'result'} {value:.4g}" if isinstance(value, (int, float)) else f"{metric} {value}"


def summary_line(task: str, metrics: str, files: str | Path | None, run_url: str | None) -> str:
    """`spacetrack <task>: <metrics> | files: <where> | MLflow: <url>`, leaving out the parts that are None
    or empty."""
    parts = [metrics] if metrics else []
    if files is not None:
        parts.append(f"files: {files}")
    if run_url is not None:
        parts.append(f"MLflow: {run_url}")
    return f"spacetrack {task}: " + " | ".join(parts)


def print_summary(task: str, metrics: str, files: str | Path | None, run_url: str | None) -> None:
    print(summary_line(task, metrics, files, run_url), flush=True)


def _in_multirun() -> bool:
    return HydraConfig.initialized() and HydraConfig.get().mode == RunMode.MULTIRUN


def shown_path(path: str | Path) -> str:
    """`path` relative to the working directory when it lies below it, else absolute."""
    path = Path(path).resolve()
    return str(path.relative_to(Path.cwd())) if path.is_relative_to(Path.cwd()) else str(path)


def _files(cfg: DictConfig, files: str | None) -> str | None:
    where = None if files is None else OmegaConf.select(cfg, files)
    return None if where is None else shown_path(str(where))


def entry_point(
    config_name: str, *, metric: str | None = None, files: str | None = None
) -> Callable[[Callable[[DictConfig], Any]], Callable[..., Any]]:
    """`@hydra.main` on conf/`config_name`.yaml with the summary line and the one-line user errors.

    metric: the name of the number the task returns (what a sweeper optimises); a task may return a
    mapping instead (every item is shown). files: the config key that says where the files went.
    Called with a config (`main(cfg)`) it runs the task alone, as `@hydra.main` does.
    """

    def decorate(task: Callable[[DictConfig], Any]) -> Callable[..., Any]:
        @functools.wraps(task)
        def task_with_summary(cfg: DictConfig) -> Any:
            with user_errors_exit():  # here, before Hydra adds its own line about the failed job
                value = task(cfg)
            if not _in_multirun():
                print_summary(
                    str(cfg.get("task_name", config_name)),
                    format_metrics(value, metric),
                    _files(cfg, files),
                    mlflow_ui.last_run_url() or NOT_LOGGED,
                )
            return value

        hydra_main = hydra.main(version_base=None, config_path=str(CONF_DIR), config_name=config_name)(
            task_with_summary
        )

        @functools.wraps(task)
        def main(cfg: DictConfig | None = None) -> Any:
            if cfg is not None:
                return task(cfg)
            return report_errors(hydra_main)

        return main

    return decorate
