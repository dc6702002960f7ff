import os

os.environ.setdefault("MUJOCO_GL", "egl")


def pytest_configure(config):
    # One torch thread: on a 2-core machine shared with other work, two threads make small
    # training runs 10-50x slower (oversubscription). Results do not depend on this.
    import torch

    torch.set_num_threads(1)
