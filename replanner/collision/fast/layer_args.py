"""The sphere layer's arrays and a map's volume as one compiled object (`LayerArgs`): the compiled checks pass it,
not 36 arrays. Python packs a call of over 30 arguments in a tuple, and numba then counts references of every array
in it, as much work as a configuration's own check."""

from __future__ import annotations

import numba
from numba.core import types
from numba.experimental import structref

_FIELDS = (
    "Fj",
    "prismatic",
    "joints",
    "parents",
    "tab_i",
    "tab_f",
    "table",
    "local",
    "rad",
    "first",
    "in_local",
    "in_rad",
    "in_first",
    "ball_slot",
    "ball_c",
    "ball_r",
    "gf",
    "env_mask",
    "ob_kind",
    "ob_inv",
    "ob_dim",
    "ob_id",
    "ob_exact",
    "ob_box",
    "octree_mask",
    "sat",
    "csat",
    "key_min",
    "inv_res",
    "pair_a",
    "pair_b",
    "fine_local",
    "fine_rad",
    "fine_ptr",
    "fine_idx",
    "whole",
)


class Unliteral(types.StructRef):
    """A compiled object's type of its fields' plain types (a literal would compile a specialization per value)."""

    def preprocess_fields(self, fields):
        return tuple((name, types.unliteral(t)) for name, t in fields)


@structref.register
class _LayerArgsType(Unliteral):
    pass


class LayerArgs(structref.StructRefProxy):
    """`SphereScene.kernel_args`: fields as named in `_FIELDS` (fast/layer.py builds it)."""


structref.define_proxy(LayerArgs, _LayerArgsType, list(_FIELDS))


@numba.njit(cache=True)
def layer_args(*args) -> LayerArgs:
    return LayerArgs(*args)
