import os

import pytest

from hupbench.cli import main
from hupbench.config import compose
from hupbench.verbs.generate import run_generate


@pytest.mark.parametrize("override, message", [
    ("dataset.sphere.r_circ_m=0.9", "r_circ_m .* must be smaller than r_sph_m"),
    ("dataset.z_ego_m=[0.5,0.0]", "z_ego_m must be a non-empty list of camera distances from 0.1 to 10.0 m"),
    ("dataset.z_ego_m=[-0.8]", "z_ego_m must be a non-empty list of camera distances from 0.1 to 10.0 m"),
    ("dataset.splits={train:7,val:2,test:3}", "add up to 12 grasps but the grasps file holds 11"),
    ("shard=3/2", "shard"),
])
def test_bad_config_fails_before_rendering(tmp_path, override, message):
    out = tmp_path / "ds"
    with pytest.raises(ValueError, match=message):
        run_generate(compose("generate", [f"out_dir={out}", override]), log=lambda *_: None)
    # nothing was rendered: no grasps, no split folders
    assert not (out / "grasps").exists() and not (out / "train").exists()


def test_backgrounds_dir_missing_or_empty(tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    for folder in (empty, tmp_path / "missing"):
        with pytest.raises(ValueError, match="no images found|not a folder|does not exist|not found"):
            run_generate(compose("generate", [f"out_dir={tmp_path / 'ds'}", f"backgrounds.dir={folder}"]),
                         log=lambda *_: None)


@pytest.mark.skipif(os.geteuid() == 0, reason="root can write anywhere")
def test_unwritable_output_as_user(tmp_path):
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o500)
    with pytest.raises(PermissionError, match="not writable"):
        run_generate(compose("generate", [f"out_dir={locked / 'ds'}"]), log=lambda *_: None)


def test_output_path_that_is_a_file(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert main(["generate", f"out_dir={blocker / 'ds'}"]) == 1
    assert capsys.readouterr().err.strip() == f"hupbench generate: error: out_dir {blocker / 'ds'} is not a folder: {blocker} is a file"


def test_verify_cli_on_a_folder_without_manifest(tmp_path, capsys):
    assert main(["verify", str(tmp_path)]) == 1
    assert "no manifest.json" in capsys.readouterr().err


def test_version_and_debug_switch(tmp_path, capsys):
    import hupbench

    with pytest.raises(SystemExit) as exit_info:
        main(["--version"])
    assert exit_info.value.code == 0
    assert capsys.readouterr().out.strip() == f"hupbench {hupbench.__version__}"
    # an error is one line without --debug, the traceback (the exception itself) with it
    assert main(["verify", str(tmp_path)]) == 1
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
    with pytest.raises((FileNotFoundError, ValueError)):
        main(["--debug", "verify", str(tmp_path)])
