"""Where the cable is drawn in a compiled model, whatever its model: one flex (rod) or capsule geoms (chain).

Perception code (hiding the cable for a background render, recolouring it for training data, reading its
pixels from a segmentation render) goes through :class:`CableLook` instead of assuming a flex.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
from numpy.typing import NDArray

from dyndlo_vision.sim import chain as chain_model
from dyndlo_vision.sim.scene import CABLE_NAME


@dataclass(frozen=True)
class CableLook:
    """The cable's drawable parts in ``model``: a flex id (rod) or the capsules' geom ids (chain)."""

    flex_id: int
    geom_ids: NDArray[np.int64]

    @classmethod
    def of(cls, model: mujoco.MjModel, name: str = CABLE_NAME) -> CableLook:
        """Find the cable named ``name`` (the scenes' :data:`CABLE_NAME`).

        Raises:
            ValueError: The model has neither a flex nor chain capsules of that name.
        """
        flex_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_FLEX, name)
        prefix = chain_model.geom_prefix(name)
        geoms = np.array(
            [g for g in range(model.ngeom) if model.geom(g).name.startswith(prefix)], dtype=np.int64
        )
        if flex_id < 0 and geoms.size == 0:
            raise ValueError(f"no cable named {name!r} in the model (neither a flex nor {prefix}* geoms)")
        return cls(int(flex_id), geoms)

    @property
    def is_flex(self) -> bool:
        return self.flex_id >= 0

    def rgba(self, model: mujoco.MjModel) -> NDArray[np.float32]:
        """The cable's colour (of its first capsule, for the chain)."""
        return (model.flex_rgba[self.flex_id] if self.is_flex else model.geom_rgba[self.geom_ids[0]]).copy()

    def set_rgba(self, model: mujoco.MjModel, rgba: NDArray[np.floating] | list[float]) -> None:
        if self.is_flex:
            model.flex_rgba[self.flex_id] = rgba
        else:
            model.geom_rgba[self.geom_ids] = rgba

    def alphas(self, model: mujoco.MjModel) -> NDArray[np.float32]:
        """The opacity of every drawn part (to hand back to :meth:`set_alphas`)."""
        if self.is_flex:
            return model.flex_rgba[[self.flex_id], 3].copy()
        return model.geom_rgba[self.geom_ids, 3].copy()

    def set_alphas(self, model: mujoco.MjModel, alpha: float | NDArray[np.floating]) -> None:
        if self.is_flex:
            model.flex_rgba[[self.flex_id], 3] = alpha
        else:
            model.geom_rgba[self.geom_ids, 3] = alpha

    def set_radius(self, model: mujoco.MjModel, radius_m: float) -> None:
        """The drawn radius. For the chain this is the capsules' radius, which collisions use too: meant for
        rendering a frozen state (training data), not for simulating on."""
        if self.is_flex:
            model.flex_radius[self.flex_id] = radius_m
        else:
            model.geom_size[self.geom_ids, 0] = radius_m
            model.geom_rbound[self.geom_ids] = radius_m + model.geom_size[self.geom_ids, 1]

    def mask(self, segmentation: NDArray[np.integer]) -> NDArray[np.bool_]:
        """Pixels of the cable in a segmentation render (``(H, W, 2)``: object id, object type)."""
        ids, types = segmentation[..., 0], segmentation[..., 1]
        if self.is_flex:
            return (types == int(mujoco.mjtObj.mjOBJ_FLEX)) & (ids == self.flex_id)
        return (types == int(mujoco.mjtObj.mjOBJ_GEOM)) & np.isin(ids, self.geom_ids)
