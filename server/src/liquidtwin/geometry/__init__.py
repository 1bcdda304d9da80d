"""Object geometry: procedural container meshes, user meshes, SDFs from meshes, volumes."""

from .mesh_io import MeshError, container_from_mesh, estimate_wall, load_mesh
from .mesh_sdf import mesh_sdf_grid
from .meshes import MODELS, build, catching_cups, model_params, pipe_junction, plate_with_bowls
from .models import basin, bottle, bowl, cup, dog_dish, fruit_bowl, ladle, mug, pan, plate
from .object_model import MIN_WALL, ObjectModel
from .volume import contains, height_for_volume, volume_below

__all__ = [
    "MeshError", "container_from_mesh", "estimate_wall", "load_mesh", "mesh_sdf_grid", "MODELS",
    "build", "catching_cups", "model_params", "pipe_junction", "plate_with_bowls", "basin",
    "bottle", "bowl", "cup", "dog_dish", "fruit_bowl", "ladle", "mug", "pan", "plate", "MIN_WALL",
    "ObjectModel", "contains", "height_for_volume", "volume_below",
]
