"""python train.py model=hopenet [key=value ...]   (-m for a sweep; torchrun for several processes)

The Hydra entry point: composes conf/train.yaml and calls hupbench.train.main (run_train, errors in one line).
Every error is one line, ``train.py: error: ...``, with exit code 1: Hydra's own (a malformed override, an
unknown key or config option) as well as the run's. HYDRA_FULL_ERROR=1 shows the traceback instead.
"""

import os
import re
import sys

import hydra
from omegaconf import DictConfig, open_dict

from hupbench.config import HYDRA_VERSION_BASE

# the user's own request for tracebacks, read before this script sets the variable for itself below
DEBUG = os.environ.get("HYDRA_FULL_ERROR") == "1"


@hydra.main(config_path="conf", config_name="train", version_base=HYDRA_VERSION_BASE)
def main(cfg: DictConfig) -> float:
    from hydra.core.hydra_config import HydraConfig

    from hupbench import train

    if cfg.run_dir is None:
        with open_dict(cfg):
            cfg.run_dir = HydraConfig.get().runtime.output_dir
    return train.main(cfg, debug=DEBUG)


def hydra_error_line(exc: BaseException) -> str:
    """Hydra's multi-line report of a malformed override, an unknown key or config option as one line."""
    from hydra.errors import OverrideParseException

    lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
    # drop Hydra's pointers (grammar link, config search path) and OmegaConf's key details
    for stop in ("See https://hydra.cc", "Config search path:"):
        lines = lines[: next((i for i, line in enumerate(lines) if line.startswith(stop)), len(lines))]
    text = " ".join(lines)
    if isinstance(exc, OverrideParseException):
        if exc.override and repr(exc.override) not in text:
            text = f"cannot parse override {exc.override!r}: {text}"
        return f"{text} (overrides are key=value, e.g. model=hopenet)"
    key = re.search(r"Could not override '([^']+)'", text)
    if key and "is not in struct" in str(exc.__cause__ or ""):
        append = re.search(r"use (\+\S+)", text)
        return (f"cannot override {key.group(1)!r}: the key is not in the config (conf/train.yaml and its groups "
                f"list the keys{f'; {append.group(1)} adds it as a new key' if append else ''})")
    return text


if __name__ == "__main__":
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    # Hydra prints its own errors over several lines (and a hint about this variable); with it set they
    # reach the handler below, which answers them in one line like every other error
    os.environ["HYDRA_FULL_ERROR"] = "1"
    try:
        main()
    except (HydraException, OmegaConfBaseException, OSError, ValueError) as exc:
        if DEBUG:
            raise
        print(f"train.py: error: {hydra_error_line(exc)}", file=sys.stderr)
        sys.exit(1)
