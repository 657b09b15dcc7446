"""python train.py [key=value ...]   (-m for a sweep; torchrun for several processes; --help lists the keys)

The same command as ``hupbench train`` (hupbench/verbs/train.py), for a git checkout and torchrun: Hydra over
conf/train.yaml, every refusal one line ``train.py: error: ...`` with exit code 1, Ctrl-C one line and exit
code 130; HYDRA_FULL_ERROR=1 shows the traceback of a refusal.
"""

import sys

from hupbench.verbs.train import command

if __name__ == "__main__":
    sys.exit(command(sys.argv[1:], prog="train.py"))
