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
