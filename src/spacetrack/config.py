"""Where the project's Hydra configs live, and small helpers shared by every entry point."""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig, OmegaConf

REPO_ROOT = Path(__file__).resolve().parents[2]
CONF_DIR = REPO_ROOT / "conf"


def resolved_dict(cfg: DictConfig) -> dict:
    """The config with every interpolation resolved, as plain containers (for logging and manifests)."""
    return OmegaConf.to_container(cfg, resolve=True, throw_on_missing=False)  # type: ignore[return-value]


def compose_config(
    config_name: str,
    overrides: list[str] | None = None,
    *,
    return_hydra_config: bool = False,
    config_dir: str | Path = CONF_DIR,
) -> DictConfig:
    """The root config `config_name` from conf/ (or `config_dir`) with command-line style `overrides`;
    with `return_hydra_config`, the `hydra` node (launcher, run folder) too.

    For notebooks, tests and one entry point calling another: inside a running `@hydra.main` app (whose
    configs are conf/ too) it composes with that app's Hydra instead of starting a second one.
    """
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    kwargs = {"overrides": overrides or [], "return_hydra_config": return_hydra_config}
    if GlobalHydra.instance().is_initialized() and Path(config_dir) == CONF_DIR:
        return compose(config_name, **kwargs)
    with initialize_config_dir(config_dir=str(config_dir), version_base=None):
        return compose(config_name, **kwargs)
