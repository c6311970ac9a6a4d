"""task: the normal equations assembled from the tree's structure equal J^T W J and -J^T W v* from the full Jacobian."""

import pytest
import torch
from conftest import random_configurations

from torchik.method.models import TRACKED_LINKS, load_model
from torchik.method.target_equations import TargetStructure, normal_equations


@pytest.mark.parametrize("name,position_links", [("human66", ("Pelvis",)), ("human48", ("Pelvis", "RightHand", "LeftToe")),
                                                  ("icub", ("root_link", "r_hand"))])
@pytest.mark.parametrize("weighted", [False, True])
def test_structured_normal_equations_equal_the_dense_ones(name, position_links, weighted):
    model = load_model(name)
    orientation_links = TRACKED_LINKS[name]
    p, R, s = random_configurations(model, 6, seed=11)
    g_ = torch.Generator().manual_seed(12)
    v_p = torch.randn(6, len(position_links), 3, generator=g_, dtype=torch.float64)
    v_o = torch.randn(6, len(orientation_links), 3, generator=g_, dtype=torch.float64)
    w_p = w_o = None
    if weighted:  # some targets dropped
        w_p = (torch.rand(6, len(position_links), generator=g_) > 0.3).double()
        w_o = (torch.rand(6, len(orientation_links), generator=g_) > 0.3).double()
    structure = TargetStructure.build(model, orientation_links, position_links)
    kin = model(p, R, s, orientation_links, jacobian=structure.position is not None, jacobian_links=structure.position,
                joint_axes=True)  # Jacobians of the position links off the base only
    H, g = normal_equations(structure, kin.joint_axes, kin.jacobian, v_p, v_o, 1e-3, w_position=w_p, w_orientation=w_o)

    J = torch.cat((model(p, R, s, position_links).jacobian[:, :, :3],
                   model(p, R, s, orientation_links).jacobian[:, :, 3:]), 1)
    w = torch.cat((torch.ones(6, len(position_links), dtype=torch.float64) if w_p is None else w_p,
                   torch.ones(6, len(orientation_links), dtype=torch.float64) if w_o is None else w_o), 1)
    J = (J * w[..., None, None]).flatten(1, 2)
    v = (torch.cat((v_p, v_o), 1) * w[..., None]).flatten(1)
    H_dense = J.transpose(1, 2) @ J + 1e-3 * torch.eye(J.shape[-1], dtype=torch.float64)
    g_dense = -(J.transpose(1, 2) @ v.unsqueeze(-1)).squeeze(-1)
    assert (H - H_dense).abs().max() < 1e-12
    assert (g - g_dense).abs().max() < 1e-12
