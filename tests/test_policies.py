import pytest
import torch

from drrl.policies import ACCEPTED_FORMS, linear, make_policy, mlp, multilinear

P, B = 5, 3


def test_linear_matches_per_candidate_matrix_product():
    policy = linear(4, 2)
    params = torch.randn(P, policy.num_params)
    obs = torch.randn(P, B, 4)
    action, state = policy.act(policy.unflatten(params), obs, None)
    assert policy.num_params == 4 * 2 + 2 and state is None
    for p in range(P):
        w, b = params[p, :8].view(4, 2), params[p, 8:]
        torch.testing.assert_close(action[p], obs[p] @ w + b)


def test_linear_without_bias_is_homogeneous():
    policy = linear(4, 1, bias=False)
    params = torch.randn(P, policy.num_params)
    obs = torch.randn(P, B, 4)
    weights = policy.unflatten(params)
    assert policy.num_params == 4
    torch.testing.assert_close(policy.act(weights, 3 * obs, None)[0], 3 * policy.act(weights, obs, None)[0])


def test_mlp_matches_torch_sequential_per_candidate():
    policy = mlp(4, 2, [8, 6])
    params = torch.randn(P, policy.num_params)
    obs = torch.randn(P, B, 4)
    action, _ = policy.act(policy.unflatten(params), obs, None)
    for p in range(P):
        net = torch.nn.Sequential(
            torch.nn.Linear(4, 8), torch.nn.Tanh(), torch.nn.Linear(8, 6), torch.nn.Tanh(), torch.nn.Linear(6, 2)
        )
        weights = policy.unflatten(params[p : p + 1])
        for layer, (w, b) in zip(net[::2], zip(weights[::2], weights[1::2], strict=True), strict=True):
            layer.weight.data = w[0].T.contiguous()
            layer.bias.data = b[0, 0]
        torch.testing.assert_close(action[p], net(obs[p]))


def test_multilinear_is_the_product_of_its_layers():
    policy = multilinear(4, 1, [3])
    params = torch.randn(P, policy.num_params)
    w1, w2 = policy.unflatten(params)
    obs = torch.randn(P, B, 4)
    torch.testing.assert_close(policy.act([w1, w2], obs, None)[0], obs @ (w1 @ w2))


def test_initial_center_starts_linear_at_origin_and_hidden_layers_random():
    assert torch.equal(linear(4, 1).initial_center(), torch.zeros(5))
    policy = mlp(4, 1, [8])
    center = policy.initial_center(torch.Generator().manual_seed(0))
    hidden, hidden_bias, output, output_bias = policy.unflatten(center[None])
    assert hidden.abs().sum() > 0 and not output.any() and not hidden_bias.any() and not output_bias.any()


def test_unflatten_rejects_the_wrong_number_of_parameters():
    with pytest.raises(ValueError, match=r"shape \(P, 5\)"):
        linear(4, 1).unflatten(torch.zeros(2, 6))


@pytest.mark.parametrize(
    "spec, num_params",
    [("linear", 5), ("linear:nobias", 4), ("multilinear:3", 15), ("mlp:8,8", 4 * 8 + 8 + 8 * 8 + 8 + 8 + 1)],
)
def test_specs_build_the_named_policy(spec, num_params):
    assert make_policy(spec, 4, 1).num_params == num_params


@pytest.mark.parametrize("spec", ["cnn", "linear:bias", "mlp", "mlp:", "mlp:0", "mlp:-4", "mlp:8,x", "multilinear:"])
def test_bad_specs_show_the_accepted_forms(spec):
    with pytest.raises(ValueError) as error:
        make_policy(spec, 4, 1)
    assert ACCEPTED_FORMS in str(error.value)


@pytest.mark.parametrize("spec", ["linear", "linear:nobias", "multilinear:4", "mlp:8,4", "rnn:5", "lstm:3,2"])
def test_folding_the_normalisation_into_the_first_layer_acts_as_normalising_the_input(spec):
    policy = make_policy(spec, 6, 2)
    generator = torch.Generator().manual_seed(0)
    params = torch.randn(3, policy.num_params, generator=generator)
    mean = torch.randn(6, generator=generator) if policy.input_bias else torch.zeros(6)  # no bias: scaling only
    std = torch.rand(6, generator=generator) + 0.5
    folded, plain = policy.initial_state(3, 4), policy.initial_state(3, 4)
    for _ in range(3):  # recurrent policies: the memory too
        obs = 3 * torch.randn(3, 4, 6, generator=generator) + 2
        on_raw, folded = policy.act(policy.unflatten(policy.fold_input(params, mean, std)), obs, folded)
        on_normalised, plain = policy.act(policy.unflatten(params), (obs - mean) / std, plain)
        torch.testing.assert_close(on_raw, on_normalised, rtol=1e-5, atol=1e-5)
    assert not torch.equal(policy.fold_input(params, mean, std), params)
