"""The bundles shipped inside the package (data only): `default/` is the model `t2m serve` uses when none is named
(T2M-HiFiGPT after 0.4.0), `gpt/` the 1-layer T2M-GPT model that was the default before, `masked/` the masked
family's; every embedded bundle can be named by its folder name wherever a bundle directory is asked for
(`--model gpt`)."""
from __future__ import annotations

import os
from pathlib import Path

__all__ = ["BUNDLE_ENVIRONMENT", "DEFAULT_BUNDLE", "EMBEDDED_BUNDLES", "GPT_BUNDLE", "configured_default_bundle",
           "resolve_bundle"]

_HERE = Path(__file__).resolve().parent
DEFAULT_BUNDLE = _HERE / "default"
GPT_BUNDLE = _HERE / "gpt"          # the embedded model of the GPT family (t2m bench sizes its GPT after it)
EMBEDDED_BUNDLES: dict[str, Path] = {path.name: path for path in sorted(_HERE.iterdir())
                                     if (path / "manifest.json").is_file()}


def resolve_bundle(path: str | Path) -> Path:
    """A bundle directory as given, or, when no such directory exists, the embedded bundle of that name."""
    given = Path(path)
    if not given.exists() and str(path) in EMBEDDED_BUNDLES:
        return EMBEDDED_BUNDLES[str(path)]
    return given


# the environment variables that name the default model's bundle, first one set wins (the service's settings read
# the same ones: t2m.service.settings.Settings.bundle_path)
BUNDLE_ENVIRONMENT = ("T2M_BUNDLE_PATH", "T2M_MODEL_DIR")


def configured_default_bundle() -> Path:
    """The default model's bundle as `t2m serve` would pick it, for the commands that run without a server."""
    for name in BUNDLE_ENVIRONMENT:
        if os.environ.get(name):
            return Path(os.environ[name])
    return DEFAULT_BUNDLE
