import pytest
import torch

from drrl.models.optimizers import AdamLambda, NesterovAG


def minimise_square(optimizer_class, steps, **settings):
    """f(θ) = θ², θ₀ = 1, float64. Returns θ after each step and where each gradient was taken."""
    theta = torch.tensor([1.0], dtype=torch.float64, requires_grad=True)
    optimizer = optimizer_class([theta], **settings)
    path, evaluated_at = [], []

    def closure():
        optimizer.zero_grad()
        evaluated_at.append(theta.item())
        loss = theta.square().sum()
        loss.backward()
        return loss

    for _ in range(steps):
        optimizer.step(closure)
        path.append(theta.item())
    return path, evaluated_at


def test_nesterov_follows_3_24_step_for_step():
    # α = 0.1, μ = 0.5, f'(θ) = 2θ.
    # 1: look-ahead 1 + 0.5·0 = 1,         g = 2,    Δ = −0.2,                θ = 0.8
    # 2: look-ahead 0.8 + 0.5·(−0.2) = 0.7, g = 1.4,  Δ = −0.1 − 0.14 = −0.24,  θ = 0.56
    # 3: look-ahead 0.56 − 0.12 = 0.44,     g = 0.88, Δ = −0.12 − 0.088 = −0.208, θ = 0.352
    path, evaluated_at = minimise_square(NesterovAG, 3, lr=0.1, momentum=0.5)
    assert path == pytest.approx([0.8, 0.56, 0.352])
    assert evaluated_at == pytest.approx([1.0, 0.7, 0.44])


def test_torch_nesterov_holds_the_look_ahead_point_instead_of_theta():
    # torch's reformulated NAG: its parameter after step t is θ_t + μΔ_t = the next look-ahead point above
    phi = torch.tensor([1.0], dtype=torch.float64, requires_grad=True)
    sgd = torch.optim.SGD([phi], lr=0.1, momentum=0.5, nesterov=True)
    path = []
    for _ in range(2):
        sgd.zero_grad()
        phi.square().sum().backward()
        sgd.step()
        path.append(phi.item())
    assert path == pytest.approx([0.7, 0.44])


def test_nesterov_refuses_to_step_without_a_closure():
    theta = torch.zeros(1, requires_grad=True)
    theta.grad = torch.ones(1)
    with pytest.raises(RuntimeError, match="needs a closure"):
        NesterovAG([theta], lr=0.1).step()


def test_adam_lambda_follows_algorithm_4_step_for_step():
    # α = 0.1, β1 = 0.9, β2 = 0.99, λ = 0.5, ε = 1e−8, gradients 1, −2, 0.5 given directly
    # t=1: β1,1 = 0.9;   m = 0.1;                      v = 0.01;           m̂ = 0.1/0.1 = 1;       v̂ = 1
    #      θ = −0.1 (up to ε)
    # t=2: β1,2 = 0.45;  m = 0.45·0.1 − 0.55·2 = −1.055; v = 0.0099 + 0.04 = 0.0499
    #      m̂ = −1.055/0.19 = −5.5526316; v̂ = 0.0499/0.0199 = 2.5075377; θ = −0.1 + 0.1·5.5526316/1.5835207 = 0.2506510
    # t=3: β1,3 = 0.225; m = −0.237375 + 0.3875 = 0.150125; v = 0.049401 + 0.0025 = 0.051901
    #      m̂ = 0.150125/0.271 = 0.5539668; v̂ = 0.051901/0.029701 = 1.7474496; θ = 0.2506510 − 0.0419065 = 0.2087445
    theta = torch.zeros(1, dtype=torch.float64, requires_grad=True)
    optimizer = AdamLambda([theta], lr=0.1, betas=(0.9, 0.99), lambda_=0.5)
    path = []
    for grad in (1.0, -2.0, 0.5):
        theta.grad = torch.tensor([grad], dtype=torch.float64)
        optimizer.step()
        path.append(theta.item())
    assert path == pytest.approx([-0.1, 0.2506510329, 0.2087445321], abs=1e-9)
    assert optimizer.state[theta]["exp_avg"].item() == pytest.approx(0.150125)


def test_adam_lambda_with_lambda_one_is_torch_adam():
    grads = torch.randn(5, 3, generator=torch.Generator().manual_seed(0))
    ours, theirs = torch.zeros(3, requires_grad=True), torch.zeros(3, requires_grad=True)
    adam_lambda = AdamLambda([ours], lr=0.01, lambda_=1.0)
    adam = torch.optim.Adam([theirs], lr=0.01)
    for grad in grads:
        ours.grad, theirs.grad = grad.clone(), grad.clone()
        adam_lambda.step()
        adam.step()
    torch.testing.assert_close(ours, theirs)


def test_adam_lambda_defaults_are_the_theses():
    group = AdamLambda([torch.zeros(1, requires_grad=True)]).param_groups[0]
    assert (group["lr"], group["betas"], group["eps"], group["lambda_"]) == (1e-3, (0.9, 0.999), 1e-8, 1 - 1e-8)


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda p: NesterovAG(p, lr=0.0), "lr must be a positive"),
        (lambda p: NesterovAG(p, lr=0.1, momentum=1.0), r"momentum must be in \[0, 1\)"),
        (lambda p: AdamLambda(p, lambda_=1.5), r"lambda_ must be in \[0, 1\]"),
        (lambda p: AdamLambda(p, betas=(1.0, 0.999)), "betas must be below 1"),
    ],
)
def test_thesis_optimizers_refuse_bad_settings(make, message):
    with pytest.raises(ValueError, match=message):
        make([torch.zeros(1, requires_grad=True)])
