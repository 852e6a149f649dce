"""The instruction sets named beside every timing (:mod:`edofproj.machine`), read from ``/proc/cpuinfo`` text."""


def test_instruction_sets_are_read_from_cpuinfo():
    from edofproj.machine import cpu_flags, instruction_sets, native_bf16

    avx2 = "processor : 0\nflags : fpu sse avx avx2 fma\n"
    bf16 = "processor : 0\nflags : avx2 fma avx512f avx512_bf16 amx_bf16\n"
    assert cpu_flags(avx2) == {"fpu", "sse", "avx", "avx2", "fma"}
    assert instruction_sets(cpu_flags(avx2)).endswith("AVX2 FMA (no native bf16)")
    assert native_bf16(cpu_flags(bf16)) and not native_bf16(cpu_flags(avx2))
    assert "AVX-512-BF16 AMX-BF16" in instruction_sets(cpu_flags(bf16))
    assert instruction_sets(set()).endswith("(CPU flags unknown)")


def test_instruction_set_limits_of_the_environment_are_honoured():
    """ATEN_CPU_CAPABILITY / ONEDNN_MAX_CPU_ISA / MKL_ENABLE_INSTRUCTIONS set to AVX2 make an AVX-512-BF16 CPU
    count as AVX2-only: no native bf16 (so ``train.mixed_precision: auto`` runs float32), and the timing's
    label names the limit and what the CPU has."""
    from edofproj.machine import isa_limits, native_bf16, usable_flags

    bf16 = {"avx2", "fma", "avx512f", "avx512_vnni", "avx512_bf16", "amx_bf16"}
    assert usable_flags(bf16, {}) == bf16
    assert usable_flags(bf16, {"ATEN_CPU_CAPABILITY": "avx2"}) == {"avx2", "fma"}
    assert usable_flags(bf16, {"ONEDNN_MAX_CPU_ISA": "AVX512_CORE"}) == {"avx2", "fma", "avx512f", "avx512_vnni"}
    assert usable_flags(bf16, {"ONEDNN_MAX_CPU_ISA": "ALL"}) == bf16
    assert not native_bf16(usable_flags(bf16, {"MKL_ENABLE_INSTRUCTIONS": "AVX2"}))
    assert isa_limits({"ONEDNN_MAX_CPU_ISA": "AVX2", "PATH": "/bin"}) == ["ONEDNN_MAX_CPU_ISA=AVX2"]


def test_the_training_precision_follows_the_limits(monkeypatch):
    import torch

    from edofproj import machine
    from edofproj.training.end_to_end import resolve_mixed_precision

    monkeypatch.setattr(machine, "cpu_flags", lambda cpuinfo=None: {"avx2", "fma", "avx512f", "avx512_bf16"})
    monkeypatch.setattr(torch.cpu, "_is_avx512_bf16_supported", lambda: True)
    for name in machine.ISA_LIMITS:
        monkeypatch.delenv(name, raising=False)
    assert resolve_mixed_precision("auto", torch.device("cpu")) == "bf16"
    monkeypatch.setenv("ONEDNN_MAX_CPU_ISA", "AVX2")
    assert resolve_mixed_precision("auto", torch.device("cpu")) == "none"
    assert "limited by ONEDNN_MAX_CPU_ISA=AVX2" in machine.instruction_sets()
    assert resolve_mixed_precision("bf16", torch.device("cpu")) == "bf16"
