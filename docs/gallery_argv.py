"""The command-line arguments sphinx-gallery gives the example scripts it runs (``reset_argv`` in conf.py).

The two examples that draw only with ``--plot FILE`` are given one, the null
device: their figure is drawn (and captured for the page) and written nowhere.
"""

import os

PLOTTING = ("ekf_slam.py", "robot_localization.py")


def reset_argv(gallery_conf, script_vars):
    """``sys.argv[1:]`` for the script `script_vars["src_file"]`."""
    return ["--plot", os.devnull] if script_vars["src_file"].endswith(PLOTTING) else []
