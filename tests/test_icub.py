"""models.icub: iCub from icub-models with its joint limits and coupled shoulder limits."""


import torch

from torchik.method.models import TRACKED_LINKS, load_model


def test_icub_has_32_revolute_joints_with_finite_limits_and_the_tracked_links():
    model = load_model("icub")
    assert model.n_dof == 32
    assert bool(torch.isfinite(model.lower).all() and (model.lower < model.upper).all())
    model.select(TRACKED_LINKS["icub"])  # every tracked link exists


def test_coupled_limits_encode_the_published_inequalities():
    model = load_model("icub")
    lim = model.linear_limits
    assert lim.A.shape == (18, 32) and lim.b.shape == (18,)
    idx = {n: i for i, n in enumerate(model.joint_names)}

    def violated(**angles):
        s = torch.zeros(32, dtype=torch.float64)
        for name, value in angles.items():
            s[idx[name]] = value
        return [name for name, a, b in zip(lim.names, lim.A, lim.b) if float(a @ s) > float(b) + 1e-12]

    # a comfortable arm pose satisfies all of them
    assert violated(r_shoulder_pitch=-0.5, r_shoulder_roll=0.6, r_shoulder_yaw=0.2, r_elbow=1.0,
                    l_shoulder_pitch=-0.5, l_shoulder_roll=0.6, l_shoulder_yaw=0.2, l_elbow=1.0) == []
    # each inequality, crossed on its own, is caught and named
    assert violated(r_shoulder_roll=0.3, l_shoulder_roll=0.6) == ["r: r + 0.0427 y >= 0.4611"]
    assert violated(r_shoulder_roll=0.6, l_shoulder_roll=1.8) == ["l: r <= 1.7453"]
    assert violated(r_shoulder_roll=0.6, l_shoulder_roll=0.6, r_elbow=2.0, r_wrist_prosup=0.3) == ["r: 2.5 e + w <= 5.2796"]
    assert "r: 1.7105 (p - r - y) <= 1.9622" in violated(r_shoulder_pitch=1.8, r_shoulder_roll=0.5, l_shoulder_roll=0.6)
