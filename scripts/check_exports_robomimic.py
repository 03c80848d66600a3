"""Checks of a demoforge robomimic export with the real `robomimic` 0.3.0 package (.venv-robomimic).

    .venv-robomimic/bin/python scripts/check_exports_robomimic.py EXPORT.hdf5 WORKDIR

Prints one line per check: CHECK {"check", "ok", "detail"} (JSON).
"""

import json
import sys
import traceback

LOW_DIM = ["robot0_eef_pos", "robot0_eef_quat", "robot0_gripper", "robot1_eef_pos", "robot1_eef_quat",
           "robot1_gripper", "object"]


def report(name, fn):
    try:
        print("CHECK " + json.dumps({"check": name, "ok": True, "detail": fn()}), flush=True)
    except Exception as e:
        traceback.print_exc(file=sys.stderr)
        print("CHECK " + json.dumps({"check": name, "ok": False, "detail": f"{type(e).__name__}: {e}"[:300]}), flush=True)


def config(path, work):
    from robomimic.config import config_factory

    c = config_factory("bc")
    with c.values_unlocked():
        c.train.data = path
        c.train.output_dir = work
        c.experiment.name = "bc_rnn_check"
        c.experiment.rollout.enabled = False
        c.experiment.render_video = False
        c.experiment.save.enabled = False
        c.experiment.logging.log_tb = False
        c.experiment.logging.log_wandb = False
        c.experiment.validate = True
        c.experiment.epoch_every_n_steps = None    # one full pass over the data = one epoch
        c.experiment.validation_epoch_every_n_steps = None
        c.train.hdf5_filter_key = "train"
        c.train.hdf5_validation_filter_key = "valid"
        c.train.num_epochs = 1
        c.train.batch_size = 16
        c.train.seq_length = 10
        c.train.num_data_workers = 0
        c.train.cuda = False
        c.algo.rnn.enabled = True
        c.algo.rnn.horizon = 10
        c.algo.gmm.enabled = True
        c.observation.modalities.obs.low_dim = LOW_DIM
        c.observation.modalities.obs.rgb = []
    return c


def check_dataset(path):
    import robomimic.utils.obs_utils as ObsUtils
    from robomimic.utils.dataset import SequenceDataset

    ObsUtils.initialize_obs_utils_with_obs_specs({"obs": {"low_dim": LOW_DIM, "rgb": []}})
    ds = SequenceDataset(hdf5_path=path, obs_keys=LOW_DIM, dataset_keys=("actions", "rewards", "dones"),
                         seq_length=10, hdf5_cache_mode="low_dim", filter_by_attribute="train")
    item = ds[0]
    assert item["actions"].shape == (10, 16) and item["obs"]["object"].shape == (10, 33)
    return f"SequenceDataset: {len(ds)} sequences of 10 steps, obs/object {item['obs']['object'].shape}"


def check_train(path, work):
    import torch
    from robomimic.scripts.train import train

    train(config(path, work), torch.device("cpu"))
    return "BC-RNN (GMM) trained one epoch on mask/train, validated on mask/valid, rollouts off"


if __name__ == "__main__":
    path, work = sys.argv[1], sys.argv[2]
    report("robomimic: SequenceDataset loads the export", lambda: check_dataset(path))
    report("robomimic: BC-RNN trains one epoch", lambda: check_train(path, work))
