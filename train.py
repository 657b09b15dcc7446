"""python train.py model=hopenet [key=value ...]   (-m for a sweep; torchrun for several processes)

The Hydra entry point: composes conf/train.yaml and calls hupbench.training.loop.main (run_train, errors in one line).
Every deliberate refusal is one line, ``train.py: error: ...``, with exit code 1: Hydra's own (a malformed override,
an unknown key or config option) as well as the run's; Ctrl-C is one line and exit code 130. Anything else is a
bug and keeps its traceback; HYDRA_FULL_ERROR=1 shows the traceback of a refusal too.
"""

import os
import sys

import hydra
from omegaconf import DictConfig, open_dict

from hupbench.config import HYDRA_VERSION_BASE
from hupbench.error_lines import hydra_error_line

# the user's own request for tracebacks, read before this script sets the variable for itself below
DEBUG = os.environ.get("HYDRA_FULL_ERROR") == "1"


@hydra.main(config_path="conf", config_name="train", version_base=HYDRA_VERSION_BASE)
def main(cfg: DictConfig) -> float:
    from hydra.core.hydra_config import HydraConfig

    from hupbench.training import loop as train

    if cfg.run_dir is None:
        with open_dict(cfg):
            cfg.run_dir = HydraConfig.get().runtime.output_dir
    return train.main(cfg, debug=DEBUG)


if __name__ == "__main__":
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    # Hydra prints its own errors over several lines (and a hint about this variable); with it set they
    # reach the handler below, which answers them in one line like every other error
    os.environ["HYDRA_FULL_ERROR"] = "1"
    try:
        main()
    except KeyboardInterrupt:
        # the loader workers, in the same process group, got the same SIGINT and end quietly
        print("train.py: interrupted (Ctrl-C); the same command continues from the run's last checkpoint",
              file=sys.stderr)
        sys.exit(130)
    except (HydraException, OmegaConfBaseException) as exc:
        if DEBUG:
            raise
        print(f"train.py: error: {hydra_error_line(exc)}", file=sys.stderr)
        sys.exit(1)
