"""Perception: liquid masks from RGB (thesis ch. 4, SPEC §6) and labels from thermal images.

``inputs.FrameEncoder`` turns RGB frames into network inputs (RGB, grey, Farnebäck flow,
fused); ``nets`` holds the FCN, multi-frame FCN and LSTM-FCN detectors with one streaming
API; ``weights`` reads and writes model files (weights_only); ``baseline`` is the thesis's
optical-flow baseline; ``metrics`` gives precision–recall with slack and its AUC;
``thermal`` makes labels from thermal frames and registers them to the colour camera
(chessboard corners, least-squares affine); ``stream`` is the live detector of a session.
"""

from .baseline import baseline_scores, flow_magnitudes
from .flow import FARNEBACK, FLOW_SCALE_PX, PerceptionInputError, encode_flow, farneback, flow_planes, grey_u8
from .inputs import FUSIONS, INPUTS, FrameEncoder, check_input, needs_flow
from .metrics import auc, pr_auc, pr_curve
from .nets import FCN, KINDS, LSTMFCN, MultiFrameFCN, build_model, parameter_count
from .thermal import (CalibrationError, apply_affine, find_chessboard, fit_affine, register_thermal,
                      synthetic_board_pair, thermal_labels, warp_labels)
from .weights import DEFAULT_MODEL, PerceptionModelError, load_model, save_model

__all__ = ["CalibrationError", "apply_affine", "find_chessboard", "fit_affine", "register_thermal",
           "synthetic_board_pair", "thermal_labels", "warp_labels", "DEFAULT_MODEL", "FARNEBACK", "FCN", "FLOW_SCALE_PX", "FUSIONS", "FrameEncoder", "INPUTS", "KINDS",
           "LSTMFCN", "MultiFrameFCN", "PerceptionInputError", "PerceptionModelError", "auc", "baseline_scores",
           "build_model", "check_input", "encode_flow", "farneback", "flow_magnitudes", "flow_planes", "grey_u8",
           "load_model", "needs_flow", "parameter_count", "pr_auc", "pr_curve", "save_model"]
