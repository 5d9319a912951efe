"""Plasma material library: QtPlasmaC material files, program magic comments, storage.

:mod:`~dthc_bridge.materials.library` holds the recipe type and the file format,
:mod:`~dthc_bridge.materials.magic` the materials programs define for themselves and the
program-time table ``M190`` selects from, :mod:`~dthc_bridge.materials.store` the daemon's
crash-safe file. Pure but for the store.
"""

from dthc_bridge.materials.library import (
    MATERIAL_KEYS,
    TEMPORARY_BASE,
    Material,
    MaterialError,
    format_material_file,
    material_from_dict,
    material_to_dict,
    parse_material_file,
)
from dthc_bridge.materials.magic import (
    MAGIC_KEYS,
    MagicMaterial,
    MaterialTable,
    parse_magic_comment,
)
from dthc_bridge.materials.store import MaterialStore

__all__ = [
    "MAGIC_KEYS",
    "MATERIAL_KEYS",
    "TEMPORARY_BASE",
    "MagicMaterial",
    "Material",
    "MaterialError",
    "MaterialStore",
    "MaterialTable",
    "format_material_file",
    "material_from_dict",
    "material_to_dict",
    "parse_magic_comment",
    "parse_material_file",
]
