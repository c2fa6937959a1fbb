"""DQN from pixels: the conv torso (shapes, [0, 255] scaling, gradients), a tiny DQN run on
rl_jax/CartPolePixels-v1 with every option (plumbing only, no learning claim), the script's run
contract (a resumed run ends bit-identical, with the frame replay in its checkpoints), and its
one-line refusals of a frame size the conv stack cannot take and of a buffer that cannot fit."""

import dataclasses
import functools

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads
from run_helpers import leaves_bytes

from rl_jax.agents import dqn as dqn_module
from rl_jax.agents.dqn import PixelConfig, dqn
from rl_jax.errors import guard
from rl_jax.run import cli, command
from rl_jax.run.checkpoint import Checkpointer
from rl_jax.run.plan import make_plan
from rl_jax.run.run_dir import CHECKPOINT_DIR
from rl_jax.training import augment, conv, networks

ENV_ID = "rl_jax/CartPolePixels-v1"


# ---- the conv torso ------------------------------------------------------------------------
def test_conv_output_sizes_follow_valid_padding():
    nature = (32, 8, 4, 64, 4, 2, 64, 3, 1)
    assert conv.conv_output_sizes(nature, 84) == [20, 9, 7]
    assert conv.conv_output_sizes((16, 8, 4, 32, 4, 2), 84) == [20, 9]
    with pytest.raises(ValueError, match="layer 3 has a 3x3 kernel but sees 2x2 pixels"):
        conv.check_conv_layers(nature, 32)
    with pytest.raises(ValueError, match="triples"):
        conv.check_conv_layers((32, 8), 84)


@pytest.mark.parametrize(
    ("layers", "band", "size", "expected"),
    [
        ((16, 8, 4, 32, 4, 2), (36, 67), 84, (34, 70)),  # CartPole's band at 84x84: 36 rows
        ((16, 8, 4, 32, 4, 2), (0, 10), 84, (0, 20)),  # grown inside the frame, not above it
        ((16, 8, 4, 32, 4, 2), (80, 84), 84, (64, 84)),
        ((8, 3, 1), (2, 5), 9, (2, 5)),  # a band the stack reads whole as it is
        ((8, 5, 5), (0, 9), 9, (0, 9)),  # no height fits: the whole frame
    ],
)
def test_covering_rows_grow_the_band_to_a_height_the_conv_stack_reads_whole(
    layers, band, size, expected
):
    first, stop = conv.covering_rows(layers, *band, size)
    assert (first, stop) == expected
    assert first <= band[0] and band[1] <= stop


def test_a_torso_that_sees_some_rows_equals_the_torso_on_those_rows():
    rows = (5, 29)
    cropped = networks.QNetwork(
        networks.Layers((8,)), 2, conv_layers=(4, 8, 4, 6, 3, 1), conv_rows=rows
    )
    whole = networks.QNetwork(networks.Layers((8,)), 2, conv_layers=(4, 8, 4, 6, 3, 1))
    frames = jax.random.randint(jax.random.key(0), (3, 36, 40, 2), 0, 256).astype(jnp.uint8)
    params = cropped.init(jax.random.key(1), frames)
    assert params["params"]["Torso_0"]["Dense_0"]["kernel"].shape == (3 * 7 * 6, 8)
    np.testing.assert_array_equal(
        cropped.apply(params, frames), whole.apply(params, frames[:, rows[0] : rows[1]])
    )


def test_the_pixel_recipe_crops_to_the_rows_cartpole_draws_on():
    config = dqn.default_config(ENV_ID)
    assert config.crop_drawn_rows and config.conv_rows() == (34, 70)
    assert dataclasses.replace(config, crop_drawn_rows=False).conv_rows() == ()
    assert dataclasses.replace(config, frame_size=42).conv_rows() == (16, 36)
    assert PixelConfig(env_id=ENV_ID).conv_rows() == ()  # off unless asked: runs saved before


# ---- DrQ's random shifts -----------------------------------------------------------------------
def test_random_shift_moves_each_image_by_one_offset_with_its_edges_repeated():
    pad, batch = 2, 500
    image = np.arange(6 * 7 * 3, dtype=np.uint8).reshape(6, 7, 3)  # every pixel distinct
    images = jnp.asarray(np.broadcast_to(image, (batch, 6, 7, 3)))
    shifted = np.asarray(
        jax.jit(augment.random_shift, static_argnums=2)(jax.random.key(0), images, pad)
    )
    assert shifted.shape == images.shape and shifted.dtype == np.uint8
    # Edge padding by hand: row/column i of the padded image is row/column clip(i - pad).
    rows = np.clip(np.arange(6 + 2 * pad) - pad, 0, 5)
    cols = np.clip(np.arange(7 + 2 * pad) - pad, 0, 6)
    padded = image[rows][:, cols]
    crops = {
        (dy, dx): padded[dy : dy + 6, dx : dx + 7]
        for dy in range(2 * pad + 1)
        for dx in range(2 * pad + 1)
    }
    seen = []
    for out in shifted:  # each output is one crop, all channels from the same offset
        matches = [offset for offset, crop in crops.items() if np.array_equal(out, crop)]
        assert len(matches) == 1
        seen.append(matches[0])
    counts = np.array([seen.count(offset) for offset in crops])
    assert counts.min() >= 5  # all 25 offsets drawn, about uniformly (expected 20 each)
    assert shifted[seen.index((0, 0))][0, 0, 0] == image[0, 0, 0]  # repeated corner pixel
    assert augment.random_shift(jax.random.key(0), images, 0) is images


def test_the_augmented_update_sees_shifted_frames_and_acting_does_not():
    # The tiny run with the shifts, after its first chunk.
    config, hparams, states, _ = tiny_run(SHIFTED_WHOLE_FRAME)
    plain = dataclasses.replace(config, augment_shift=0)
    state = states[1]
    args = (state.agent, state.buffer, jax.random.key(3))
    update = jax.jit(dqn_module.update, static_argnums=3)
    shifted, _, shifted_metrics = update(*args, config, hparams, 200)
    unshifted, _, metrics = update(*args, plain, hparams, 200)
    again, _, _ = update(*args, config, hparams, 200)
    differs = jax.tree.map(lambda a, b: bool(jnp.any(a != b)), shifted.online, unshifted.online)
    assert all(jax.tree.leaves(differs))  # the loss saw other pixels
    assert float(shifted_metrics["loss"]) != float(metrics["loss"])
    jax.tree.map(np.testing.assert_array_equal, shifted.online, again.online)  # deterministic
    np.testing.assert_array_equal(  # acting reads the frames as they are
        dqn_module.act(state.agent, state.obs, config),
        dqn_module.act(state.agent, state.obs, plain),
    )


def test_q_network_on_frames_has_the_right_shapes_for_any_batch_dims():
    net = networks.QNetwork(
        networks.Layers((32,)), 2, dueling=True, conv_layers=(16, 8, 4, 32, 4, 2)
    )
    frames = jax.random.randint(jax.random.key(0), (2, 3, 44, 44, 4), 0, 256).astype(jnp.uint8)
    params = jax.jit(net.init)(jax.random.key(1), frames[0, 0])
    assert params["params"]["ConvTorso_0"]["Conv_1"]["kernel"].shape == (4, 4, 16, 32)
    assert params["params"]["Torso_0"]["Dense_0"]["kernel"].shape == (4 * 4 * 32, 32)
    apply = jax.jit(net.apply)
    q = apply(params, frames)
    assert q.shape == (2, 3, 2) and q.dtype == jnp.float32
    np.testing.assert_allclose(apply(params, frames[1, 2]), q[1, 2], rtol=1e-5, atol=1e-6)


def test_pixels_are_scaled_to_unit_range_inside_the_network():
    torso = conv.ConvTorso((4, 3, 1))
    frames = jax.random.randint(jax.random.key(0), (2, 6, 6, 1), 0, 256).astype(jnp.uint8)
    params = torso.init(jax.random.key(1), frames)
    first = {"params": params["params"]["Conv_0"]}
    expected = nn.relu(nn.Conv(4, (3, 3), padding="VALID").apply(first, frames / 255.0))
    np.testing.assert_allclose(
        torso.apply(params, frames), expected.reshape(2, -1), rtol=1e-5, atol=1e-6
    )


# (kernel, stride, frame size) with 5 channels into 7 features: the strided layers sum per-tap
# products, the 3x3 stride-1 layers (as MinAtar's) multiply patches; both layouts are covered.
MATMUL_CONV_CASES = [
    (8, 4, 84),
    (8, 4, 42),
    (4, 2, 20),
    (4, 2, 9),
    (3, 1, 7),
    (3, 1, 10),
    (3, 2, 9),
    (5, 3, 17),
]


# Cases that also run with each layout forced (``MatmulConv.layout``): a strided layer whose
# stride divides the kernel, one whose stride does not (a zero-padded kernel), and MinAtar's.
FORCED_LAYOUT_CASES = [(8, 4, 42), (5, 3, 17), (3, 1, 10)]


def _layout(kernel: int, stride: int, size: int) -> bool:
    out = (size - kernel) // stride + 1
    blocks = out + -(-kernel // stride) - 1
    return conv.uses_patches((out, out), (blocks, blocks), stride * stride * 5, 7)


def test_matmul_conv_cases_cover_both_layouts():
    assert {_layout(*case) for case in MATMUL_CONV_CASES} == {True, False}
    assert _layout(3, 1, 10) and not _layout(8, 4, 84)
    forced = {_layout(*case) for case in FORCED_LAYOUT_CASES}
    assert set(FORCED_LAYOUT_CASES) <= set(MATMUL_CONV_CASES) and forced == {True, False}


def test_matmul_conv_rejects_an_unknown_layout():
    layer = conv.MatmulConv(7, 3, 1, layout="im2col")
    with pytest.raises(ValueError, match="unknown MatmulConv layout 'im2col'.*'patches'"):
        layer.init(jax.random.key(0), jnp.zeros((1, 5, 5, 2)))


@pytest.mark.parametrize(
    "kernel, stride, size, layout",
    [(*case, "auto") for case in MATMUL_CONV_CASES]
    + [(*case, layout) for case in FORCED_LAYOUT_CASES for layout in ("patches", "products")],
)
def test_matmul_conv_equals_flax_conv_and_its_gradients(kernel, stride, size, layout):
    """MatmulConv (space-to-depth, then one matmul) against nn.Conv with the same parameters:
    outputs, parameter gradients and input gradients, strides that divide the kernel or not,
    in both of its layouts (summed per-tap products, or patches), as ``auto`` picks them and
    forced."""
    # Each side's forward pass and gradients as one jitted program: run op by op, every one of
    # their many primitives would compile a program of its own for each of these shapes.
    x = jax.random.normal(jax.random.key(1), (2, 3, size, size, 5))
    layer = conv.MatmulConv(7, kernel, stride, layout=layout)
    params = jax.jit(layer.init)(jax.random.key(0), x)
    reference = nn.Conv(7, (kernel, kernel), (stride, stride), "VALID")
    np.testing.assert_allclose(
        jax.jit(layer.apply)(params, x), jax.jit(reference.apply)(params, x), rtol=1e-5, atol=1e-5
    )

    def grads(module):
        def objective(params, x):
            return jnp.sum(jnp.sin(module.apply(params, x)))

        return jax.jit(jax.grad(objective, argnums=(0, 1)))(params, x)

    for got, expected in zip(
        jax.tree.leaves(grads(layer)), jax.tree.leaves(grads(reference)), strict=True
    ):
        scale = float(jnp.max(jnp.abs(expected)))
        np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-5 * scale)


def test_conv_q_network_gradients_match_finite_differences():
    net = networks.QNetwork(networks.Layers((6,)), 3, conv_layers=(3, 3, 2, 4, 2, 1))
    frames = jax.random.uniform(jax.random.key(0), (2, 9, 9, 2), minval=0.0, maxval=255.0)
    params = net.init(jax.random.key(1), frames)

    @jax.jit
    def loss(params, frames):
        return jnp.sum(jnp.tanh(net.apply(params, frames)))

    check_grads(loss, (params, frames), order=1, modes=["rev"], atol=2e-2, rtol=2e-2, eps=1e-2)


# ---- DQN on pixels ---------------------------------------------------------------------------
TINY = {
    "frame_size": 36,
    "conv_layers": (8, 8, 4, 8, 3, 1),
    "hidden": (16,),
    "num_envs": 2,
    "updates_per_iteration": 2,
    "iterations_per_chunk": 100,
    "learning_starts": 60,
    "batch_size": 8,
    "buffer_size": 64,  # wraps within the run
    "num_eval_envs": 2,
    "target_update_period": 10,
}
# The torso over the whole frame (the recipe crops) and DrQ's random shifts in the loss: two
# options apart from the recipe that touch different parts (the torso's input, the loss's
# frames), trained together in one compiled program.
SHIFTED_WHOLE_FRAME = {"crop_drawn_rows": False, "augment_shift": 2}


def tiny_run(options: dict) -> tuple:
    """``(config, hparams, [initial state, state after chunk 1, after chunk 2], last metrics)``
    of the tiny run with ``options``, trained once for every test that reads it."""
    return _tiny_run(tuple(sorted(options.items())))


@functools.cache
def _tiny_run(options: tuple) -> tuple:
    config = dqn.default_config(ENV_ID, **TINY, **dict(options))
    hparams = dqn.default_hyperparams(ENV_ID)
    states = [dqn.init(jax.random.key(0), config, hparams)]
    chunk = jax.jit(dqn.train_chunk, static_argnums=1)
    for _ in range(2):
        state, metrics = chunk(states[-1], config, hparams)
        states.append(state)
    return config, hparams, states, metrics


@pytest.mark.parametrize(
    "options",
    [
        {"double": False, "n_step": 1},  # plain DQN (the pixel recipe is Double with 3 steps)
        {"double": True, "dueling": True, "n_step": 3, "prioritized": True},
        SHIFTED_WHOLE_FRAME,
    ],
)
def test_a_tiny_dqn_run_on_pixels_trains_and_evaluates(options):
    config, _, (first, _, state), metrics = tiny_run(options)
    assert isinstance(config, PixelConfig)
    assert first.obs.shape == (2, 36, 36, 4) and first.obs.dtype == jnp.uint8
    before = first.agent.online
    assert int(metrics.env_steps) == 400 and int(metrics.updates) == 2 * (200 - 30)
    assert int(state.buffer.written) == 200 and state.buffer.frames.dtype == jnp.uint8
    assert np.isfinite(float(metrics.extra["loss"])) and float(metrics.eval_return) >= 8.0
    moved = jax.tree.map(lambda a, b: bool(jnp.any(a != b)), before, state.agent.online)
    assert all(jax.tree.leaves(moved))
    action = dqn.policy(state, config)(state.obs[0])
    assert action.shape == () and action.dtype == jnp.int32


def _run(argv: list[str]) -> int:
    return guard(lambda: cli.run_experiment(dqn, ENV_ID, "", argv))


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["--frame-size", "16"], "layer 2 has a 4x4 kernel but sees 3x3 pixels"),
        (["--conv-layers", "16,8"], "(features, kernel, stride) triples"),
        (["--augment-shift", "84"], "augment_shift must be in 0..83, got 84"),
        (["--buffer-size", "5000000", "--seeds", "3"], "the train state needs "),
    ],
)
def test_bad_input_is_one_line_before_anything_compiles(tmp_path, capsys, argv, expected):
    out = tmp_path / "run"
    status = _run([*argv, "--out", str(out)])
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert status == 2 and len(lines) == 1 and lines[0].startswith("error: "), captured.err
    assert expected in lines[0] and "compiling" not in captured.out
    assert not out.exists()


# ---- the script's run contract -------------------------------------------------------------
FLAGS = [
    "--frame-size", "36", "--conv-layers", "8,8,4,8,3,1", "--hidden", "16", "--num-envs", "2",
    "--iterations-per-chunk", "100", "--learning-starts", "60", "--batch-size", "8",
    "--buffer-size", "64", "--num-eval-envs", "2", "--seeds", "2", "--log-interval", "0",
    "--checkpoint-interval", "0",
]  # fmt: skip


def _final_state(run_dir):
    spec = command.spec_for(dqn, ENV_ID, FLAGS)
    plan = make_plan(dataclasses.replace(spec, out=run_dir))
    with Checkpointer(run_dir / CHECKPOINT_DIR, read_only=True) as checkpointer:
        return checkpointer.restore(plan.template)[0]


def test_a_resumed_pixel_run_ends_bit_identical_to_an_unstopped_one(tmp_path):
    whole, split = tmp_path / "whole", tmp_path / "split"
    assert _run([*FLAGS, "--total-steps", "400", "--out", str(whole)]) == 0
    assert _run([*FLAGS, "--total-steps", "200", "--out", str(split)]) == 0
    assert _run(["--resume", str(split), "--total-steps", "400"]) == 0
    whole_state, split_state = _final_state(whole), _final_state(split)
    assert np.asarray(whole_state.buffer.written).tolist() == [[200, 200]]
    assert leaves_bytes(whole_state) == leaves_bytes(split_state)
    assert (whole / "curves.png").is_file() and (whole / "metrics.jsonl").is_file()
