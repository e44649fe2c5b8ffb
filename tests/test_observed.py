"""Space no training camera sees has zero density (lift3d.train.observed + SceneSpace.observed)."""

import numpy as np
import pytest
import torch

from lift3d.data.cameras import Cameras, look_at
from lift3d.field.grid import GridField, GridFieldConfig
from lift3d.field.registry import FieldConfig
from lift3d.field.space import SceneSpace
from lift3d.train.observed import observed_cells


def one_camera(eye, target):
    return Cameras(c2w=look_at(np.asarray(eye, float), np.asarray(target, float))[None],
                   fx=np.array([16.0]), fy=np.array([16.0]), cx=np.array([16.0]), cy=np.array([16.0]),
                   width=np.array([32]), height=np.array([32]))


def test_cells_behind_the_only_camera_are_unobserved():
    cams = one_camera([0.0, -0.5, 0.0], [0.0, 1.0, 0.0])  # at y = -0.5, looking along +y (90° field of view)
    space = SceneSpace("none")
    mask = observed_cells(space, cams, [0], 16, near=0.05, dilate=0)
    centers = space.cell_centers(16).numpy()
    y = centers[..., 1]
    assert not mask[torch.from_numpy(y < -0.55)].any()  # behind the camera
    ahead = (y > 0.5) & (np.abs(centers[..., 0]) < 0.5) & (np.abs(centers[..., 2]) < 0.5)
    assert mask[torch.from_numpy(ahead)].all()  # well inside the frustum
    assert 0.1 < mask.float().mean() < 0.6
    # Dilation only ever adds cells.
    dilated = observed_cells(space, cams, [0], 16, near=0.05, dilate=1)
    assert (dilated | mask).equal(dilated) and dilated.sum() > mask.sum()


def test_cells_outside_the_declared_scene_box_are_unobserved():
    cams = one_camera([0.0, -0.5, 0.0], [0.0, 1.0, 0.0])
    space = SceneSpace("none")
    box = np.array([[-0.5, -1.0, -0.25], [0.5, 1.0, 0.25]])
    mask = observed_cells(space, cams, [0], 16, near=0.05, dilate=0, box=box)
    free = observed_cells(space, cams, [0], 16, near=0.05, dilate=0)
    c = space.cell_centers(16).numpy()
    inside = torch.from_numpy(((c >= box[0]) & (c <= box[1])).all(-1))
    assert not mask[~inside].any()
    assert mask[inside].equal(free[inside])  # inside the box the cameras still decide
    # One cell of dilation lets a surface lying on the box's face keep its density.
    dilated = observed_cells(space, cams, [0], 16, near=0.05, dilate=1, box=box)
    assert dilated[~inside].any() and (dilated | mask).equal(dilated)


def test_unobserved_cells_have_zero_density_and_survive_a_checkpoint():
    cfg = FieldConfig(num_semantic_classes=3, num_instance_channels=0, contraction="none",
                      grid=GridFieldConfig(max_resolution=16, min_resolution=8, head_hidden_dim=8))
    field = GridField(cfg)
    behind, ahead = torch.tensor([[0.0, -0.9, 0.0]]), torch.tensor([[0.0, 0.5, 0.0]])
    assert field.geometry(behind)[0].item() > 0  # the opaque start
    cams = one_camera([0.0, -0.5, 0.0], [0.0, 1.0, 0.0])
    field.space.observed = observed_cells(field.space, cams, [0], 16, near=0.05)
    assert field.geometry(behind)[0].item() == 0.0 and field.geometry(ahead)[0].item() > 0
    # The lattice is part of the state: a fresh field loads it; a checkpoint without it means "all observed".
    fresh = GridField(cfg)
    fresh.load_state_dict(field.state_dict())
    assert fresh.geometry(behind)[0].item() == 0.0
    old = {k: v for k, v in field.state_dict().items() if not k.endswith("observed")}
    legacy = GridField(cfg)
    legacy.load_state_dict(old)
    assert legacy.geometry(behind)[0].item() > 0


def test_a_set_box_zeroes_density_exactly_at_its_faces_and_bounds_the_rays():
    from lift3d.render.renderer import SamplingConfig, near_far

    cfg = FieldConfig(num_semantic_classes=3, num_instance_channels=0, contraction="none",
                      grid=GridFieldConfig(max_resolution=16, min_resolution=8, head_hidden_dim=8))
    field = GridField(cfg)
    # A ceiling at z = 0.30 inside a cell of the 16³ lattice (cells 0.125 wide): whole-cell clipping keeps
    # density up to z = 0.375, the box none above 0.30.
    field.space.set_box([-1.0, -0.5, -0.4], [1.0, 0.5, 0.30])
    below, above = torch.tensor([[0.0, 0.0, 0.29]]), torch.tensor([[0.0, 0.0, 0.31]])
    assert field.geometry(below)[0].item() > 0 and field.geometry(above)[0].item() == 0.0
    x = torch.tensor([[0.0, 0.0, 0.31], [0.0, 0.6, 0.0], [0.0, 0.2, 0.0]])
    assert field.space(x)[1].tolist() == [False, False, True]
    assert field.space.forward_torch(x)[1].tolist() == [False, False, True]  # the reference path agrees
    # Rays start and stop at the box, not at the cube around it.
    origins = torch.tensor([[0.0, 0.0, 0.0], [0.0, -0.9, 0.0]])
    dirs = torch.tensor([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])
    near, far = near_far(origins, dirs, SamplingConfig(near_plane=0.01), True, field.space.ray_bounds())
    assert torch.allclose(near, torch.tensor([0.01, 0.4])) and torch.allclose(far, torch.tensor([0.30, 1.4]))
    # Without a box: the cube.
    near, far = near_far(origins, dirs, SamplingConfig(near_plane=0.01), True, SceneSpace("none").ray_bounds())
    assert torch.allclose(far, torch.tensor([1.0, 1.9]))
    # The occupancy grid measures a cell the box's face cuts inside the box; points a cell beyond stay outside.
    moved = field.space.clamp_to_box(torch.tensor([[0.0, 0.0, 0.35], [0.0, 0.0, 0.9]]), reach=0.125)
    assert torch.allclose(moved, torch.tensor([[0.0, 0.0, 0.30], [0.0, 0.0, 0.9]]))
    with pytest.raises(ValueError, match="lower < upper"):
        field.space.set_box([0.0, 0.0, 0.0], [1.0, -1.0, 1.0])
    with pytest.raises(ValueError, match="bounded"):
        SceneSpace("linf").set_box([0.0] * 3, [1.0] * 3)


@pytest.mark.parametrize("contraction", ["linf", "l2"])
def test_contracted_lattice_centres_map_back_to_their_cells(contraction):
    space = SceneSpace(contraction)
    x = space.cell_centers(8).reshape(-1, 3)
    finite = torch.isfinite(x).all(-1)
    # linf fills the cube; l2's ball leaves the cube's corner cells unreachable (infinitely far).
    assert finite.all() if contraction == "linf" else 0.4 < finite.float().mean() < 1.0
    u, valid = space(x[finite].float())
    cells = ((u * 8).floor().long())
    grid = torch.stack(torch.meshgrid(*[torch.arange(8)] * 3, indexing="ij"), -1).reshape(-1, 3)[finite]
    assert valid.all() and torch.equal(cells, grid)
