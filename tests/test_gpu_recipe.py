"""bench/gpu_recipe.py's table: when the seed mean first reached the goal, read from a run's files
(the GPU check runs the candidates; here a made-up run stands in)."""

import json

from bench import gpu_recipe


def test_table_gives_the_first_evaluation_at_the_goal_and_the_loop_rates(tmp_path):
    run = tmp_path / "runs" / "e64-b1024-u32"
    run.mkdir(parents=True)
    rows = []
    for chunk, (step, returns) in enumerate([(16384, (100, 300)), (32768, (4900, 5300))]):
        for seed, value in enumerate(returns):
            wall_time, updates = 20.0 + 10 * chunk, 8192 * chunk
            rows.append(
                {"step": step, "seed": seed, "eval_return": value, "updates": updates,
                 "wall_time": wall_time}
            )  # fmt: skip
    (run / "metrics.jsonl").write_text("".join(json.dumps(row) + "\n" for row in rows))
    curve = [
        {"step": 16384, "mean": 200.0, "wall_time": 20.0, "train_s": 9.6},
        {"step": 32768, "mean": 5100.0, "wall_time": 30.0, "train_s": 19.7},
    ]
    record = {"name": run.name, "stopped_by": "goal", "compile_s": 41.5, "curve": curve}
    (run / "stop.json").write_text(json.dumps(record))
    row = gpu_recipe.table(tmp_path, 5000.0).splitlines()[2]
    cells = [cell.strip() for cell in row.strip("|").split("|")]
    assert cells[:9] == ["e64-b1024-u32", "64", "1,024", "32", "0.5", "42", "32,768", "20", "30"]
    # 16,384 env steps and 8,192 updates per seed in the 10 s between the two evaluations
    assert cells[9:] == ["5,100 (32,768, 20)", "1,638", "819", "goal"]


def test_candidate_flags_name_the_loop():
    args = gpu_recipe.flags("e256-b4096-u64", dry=False)
    values = dict(zip(args[::2], args[1::2], strict=True))
    assert values["--seeds"] == "5"
    assert (values["--num-envs"], values["--batch-size"]) == ("256", "4096")
    assert values["--updates-per-iteration"] == "64"
    assert int(values["--iterations-per-chunk"]) * 256 == gpu_recipe.CHUNK_STEPS
    assert "--base-seed" not in values  # seeds 0-4 unless asked


def test_another_seed_set_changes_only_the_first_seed():
    first = gpu_recipe.flags("e64-b1024-u32", dry=False)
    other = gpu_recipe.flags("e64-b1024-u32", dry=False, base_seed=5)
    values = dict(zip(other[::2], other[1::2], strict=True))
    assert values["--base-seed"] == "5"
    at = other.index("--base-seed")
    assert other[:at] + other[at + 2 :] == first


def test_the_gpu_recipe_is_the_candidate_that_reached_the_goal():
    """td3_cheetah.py --recipe gpu trains the loop that bench/gpu_recipe.py timed on the H100."""
    from rl_jax.agents import td3

    args = gpu_recipe.flags("e64-b1024-u32", dry=False)
    values = dict(zip(args[::2], args[1::2], strict=True))
    config = td3.GPU_CHEETAH_CONFIG
    assert int(values["--num-envs"]) == config["num_envs"]
    assert int(values["--batch-size"]) == config["batch_size"]
    assert int(values["--updates-per-iteration"]) == config["updates_per_iteration"]
    assert int(values["--iterations-per-chunk"]) == config["iterations_per_chunk"]
    assert int(values["--buffer-size"]) == config["buffer_size"]
    assert float(values["--actor-lr"]) == td3.FAST_CHEETAH_HPARAMS["actor_lr"]
    assert float(values["--critic-lr"]) == td3.FAST_CHEETAH_HPARAMS["critic_lr"]
    assert config["actor_hidden"] == config["critic_hidden"] == (128, 128)  # the script's default
