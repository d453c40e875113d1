import itertools

import pytest
import torch

from drrl.search import OPTIMIZERS, ClipUp, make_optimizer


def clipup_steps(grads, **settings):
    x = torch.zeros(2, requires_grad=True)
    optimizer = ClipUp([x], **settings)
    path = []
    for grad in grads:
        x.grad = torch.tensor(grad)
        optimizer.step()
        path.append(x.detach().clone())
    return path, optimizer


def test_clipup_matches_a_hand_computed_reference():
    # lr 0.5, momentum 0.9, max_speed 0.8; p.grad is the loss gradient, so ClipUp climbs g = -grad
    path, _ = clipup_steps([[3.0, 4.0], [3.0, 4.0], [0.0, -2.0]], lr=0.5, momentum=0.9, max_speed=0.8)
    # 1: g/|g| = -(0.6, 0.8); v = 0.5 · that = (-0.3, -0.4), |v| = 0.5 <= 0.8; x = (-0.3, -0.4)
    torch.testing.assert_close(path[0], torch.tensor([-0.3, -0.4]))
    # 2: v = 0.9 · (-0.3, -0.4) + (-0.3, -0.4) = (-0.57, -0.76), |v| = 0.95 > 0.8 → v = (-0.48, -0.64)
    #    x = (-0.78, -1.04)
    torch.testing.assert_close(path[1], torch.tensor([-0.78, -1.04]))
    # 3: g/|g| = (0, 1); v = 0.9 · (-0.48, -0.64) + 0.5 · (0, 1) = (-0.432, -0.076), |v| ≈ 0.439 <= 0.8
    #    x = (-1.212, -1.116)
    torch.testing.assert_close(path[2], torch.tensor([-1.212, -1.116]))


def test_clipup_defaults_to_momentum_0_9_and_max_speed_twice_the_step():
    path, optimizer = clipup_steps([[0.0, 10.0]] * 30, lr=0.1)
    assert optimizer.param_groups[0]["momentum"] == 0.9
    assert optimizer.param_groups[0]["max_speed"] == pytest.approx(0.2)
    steps = [b - a for a, b in itertools.pairwise([torch.zeros(2), *path])]
    assert max(step.norm().item() for step in steps) == pytest.approx(0.2)  # reached, never exceeded
    torch.testing.assert_close(steps[0], torch.tensor([0.0, -0.1]))


def test_clipup_ignores_a_zero_gradient_without_nans():
    path, _ = clipup_steps([[0.0, 0.0], [1.0, 0.0], [0.0, 0.0]], lr=0.5, momentum=0.5, max_speed=10.0)
    torch.testing.assert_close(path[0], torch.zeros(2))
    torch.testing.assert_close(path[1], torch.tensor([-0.5, 0.0]))
    torch.testing.assert_close(path[2], torch.tensor([-0.75, 0.0]))  # momentum only: v = 0.5 · (-0.5, 0)


def test_clipup_state_round_trips_through_torch_state_dict():
    _, optimizer = clipup_steps([[1.0, 2.0]], lr=0.1)
    x = torch.zeros(2, requires_grad=True)
    copy = ClipUp([x], lr=0.1)
    copy.load_state_dict(optimizer.state_dict())
    torch.testing.assert_close(copy.state[x]["velocity"], optimizer.state_dict()["state"][0]["velocity"])


@pytest.mark.parametrize(
    "settings, message",
    [
        (dict(lr=0.0), "lr must be a positive finite number"),
        (dict(lr=0.1, max_speed=-1.0), "max_speed must be a positive finite number"),
        (dict(lr=0.1, momentum=1.0), r"momentum must be in \[0, 1\)"),
    ],
)
def test_clipup_refuses_bad_settings(settings, message):
    with pytest.raises(ValueError, match=message):
        ClipUp([torch.zeros(2, requires_grad=True)], **settings)


def test_make_optimizer_uses_torch_optimizers_where_they_exist():
    x = torch.zeros(2, requires_grad=True)
    assert type(make_optimizer("sgd", [x], 0.1)) is torch.optim.SGD
    adam = make_optimizer("adam", [x], 0.1, {"betas": [0.8, 0.9]})
    assert type(adam) is torch.optim.Adam and adam.param_groups[0]["betas"] == (0.8, 0.9)
    assert type(make_optimizer("clipup", [x], 0.1, {"max_speed": 0.3})) is ClipUp
    assert OPTIMIZERS == ("sgd", "adam", "clipup")
    with pytest.raises(ValueError, match="choose one of: sgd, adam, clipup"):
        make_optimizer("lion", [x], 0.1)
