"""Where the project's Hydra configs live, and small helpers shared by every entry point."""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig, OmegaConf

REPO_ROOT = Path(__file__).resolve().parents[2]
CONF_DIR = REPO_ROOT / "conf"


def resolved_dict(cfg: DictConfig) -> dict:
    """The config with every interpolation resolved, as plain containers (for logging and manifests)."""
    return OmegaConf.to_container(cfg, resolve=True, throw_on_missing=False)  # type: ignore[return-value]


def compose_config(config_name: str, overrides: list[str] | None = None) -> DictConfig:
    """The root config `config_name` from conf/ with command-line style `overrides`.

    For notebooks, tests and one entry point calling another: inside a running `@hydra.main` app (whose
    configs are conf/ too) it composes with that app's Hydra instead of starting a second one.
    """
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    if GlobalHydra.instance().is_initialized():
        return compose(config_name, overrides=overrides or [])
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base=None):
        return compose(config_name, overrides=overrides or [])
