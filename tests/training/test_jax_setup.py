"""Process-wide JAX settings: the compilation cache is kept apart per CPU."""

import re

from rl_jax.training import jax_setup


def test_the_default_cache_is_one_directory_per_cpu_tag():
    tag = jax_setup.cpu_tag()
    assert re.fullmatch(r"[0-9a-f]{12}", tag) and jax_setup.cpu_tag() == tag
    assert jax_setup.CACHE_ROOT / tag == jax_setup.DEFAULT_CACHE_DIR


def test_the_tag_follows_the_instruction_set(monkeypatch):
    """Two CPUs that differ only in their flags (AVX-512 or not) get different caches."""
    import builtins
    import io

    real_open = builtins.open

    def cpuinfo(flags):
        def fake_open(path, *args, **kwargs):
            if str(path) == "/proc/cpuinfo":
                return io.StringIO(f"model name\t: EPYC\nflags\t\t: {flags}\n")
            return real_open(path, *args, **kwargs)

        return fake_open

    monkeypatch.setattr(builtins, "open", cpuinfo("avx2 fma"))
    without = jax_setup.cpu_tag()
    monkeypatch.setattr(builtins, "open", cpuinfo("avx2 fma avx512f avx512_bf16"))
    assert jax_setup.cpu_tag() != without
