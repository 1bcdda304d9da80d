"""Discrepancy discovery: what the simulation gets wrong, why, and how much a fix gains.

>>> report = analyse(["pour.mcap"], "out/")      # report.json, report.md, PNGs in out/
>>> report["decision"]                             # "drag", …, "none" or "unexplained"
>>> ext = load_model("out/model.json")            # the extended model, for a session
"""

from .analysis import Options, analyse
from .candidates import LIBRARY, fit_candidate, main_value
from .episode import Episode, load_episode
from .model import CANDIDATES, Extension, apply_physics, camera_for, load_model, model_from_dict, save_model
from .rollout import Simulator, Trajectory

__all__ = ["Options", "analyse", "LIBRARY", "fit_candidate", "main_value", "Episode", "load_episode", "CANDIDATES",
           "Extension", "apply_physics", "camera_for", "load_model", "model_from_dict", "save_model", "Simulator",
           "Trajectory"]
