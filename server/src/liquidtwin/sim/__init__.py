"""SPNets core: neighbour search, ConvSP, ConvSDF and the differentiable PBF step."""

from .convsp import ConvSP, convsp
from .kernels import KERNELS, kernel_value
from .neighbors import Neighbors, brute_force_neighbors, cell_order, find_neighbors
from .packing import calibrate, lattice, particle_radius, particle_volume
from .pbf import (ITERATIONS_PER_PENETRATION, LAYERS_PER_ITERATION, FluidModel, FluidParams, FluidState, collide_move,
                  iterations_for_depth, iterations_for_impact, make_state, rollout, step)
from .sdf import SDFGrid, conv_sdf, interpolate_poses, min_sdf, push_out, quat_from_axis_angle, quat_to_matrix
from .sdf_ops import carve, cylinder_sdf, solidify
from .terms import LinearAcceleration, LinearDrag, QuadraticDrag, Term, UniformAcceleration, WallAdhesion

__all__ = [
    "ConvSP", "convsp", "KERNELS", "kernel_value", "Neighbors", "brute_force_neighbors", "cell_order",
    "find_neighbors", "calibrate", "lattice", "particle_radius", "particle_volume", "FluidModel", "FluidParams", "FluidState",
    "collide_move", "make_state", "rollout", "step", "LAYERS_PER_ITERATION", "iterations_for_depth",
    "ITERATIONS_PER_PENETRATION", "iterations_for_impact", "SDFGrid", "conv_sdf", "interpolate_poses", "min_sdf",
    "push_out", "quat_from_axis_angle", "quat_to_matrix", "LinearAcceleration", "LinearDrag", "QuadraticDrag", "Term", "UniformAcceleration", "WallAdhesion",
    "carve", "cylinder_sdf", "solidify",
]
