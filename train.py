"""python train.py model=hopenet [key=value ...]   (-m for a sweep; torchrun for several processes)

The Hydra entry point: composes conf/train.yaml and calls hupbench.train.main (run_train, errors in one line).
"""

import hydra
from omegaconf import DictConfig, open_dict

from hupbench.config import HYDRA_VERSION_BASE


@hydra.main(config_path="conf", config_name="train", version_base=HYDRA_VERSION_BASE)
def main(cfg: DictConfig) -> float:
    from hydra.core.hydra_config import HydraConfig

    from hupbench import train

    if cfg.run_dir is None:
        with open_dict(cfg):
            cfg.run_dir = HydraConfig.get().runtime.output_dir
    return train.main(cfg)


if __name__ == "__main__":
    main()
