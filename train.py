"""python train.py model=hopenet [key=value ...]   (-m for a sweep; torchrun for several processes)

The Hydra entry point: composes conf/train.yaml and calls hupbench.train.run_train.
"""

import sys

import hydra
from omegaconf import DictConfig, open_dict

from hupbench.config import HYDRA_VERSION_BASE


@hydra.main(config_path="conf", config_name="train", version_base=HYDRA_VERSION_BASE)
def main(cfg: DictConfig) -> float:
    from hydra.core.hydra_config import HydraConfig

    from hupbench.train import run_train

    if cfg.run_dir is None:
        with open_dict(cfg):
            cfg.run_dir = HydraConfig.get().runtime.output_dir
    try:
        result = run_train(cfg)
    except (ValueError, TypeError, FileNotFoundError, RuntimeError) as exc:
        print(f"train.py: error: {exc}", file=sys.stderr)
        sys.exit(1)
    return result["val_mpjpe_mm"]["all"]


if __name__ == "__main__":
    main()
