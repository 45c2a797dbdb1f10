"""Print the NPY_DISABLE_CPU_FEATURES value for `make test-portable`.

numpy picks SIMD code for many ufuncs at run time (``power``, ``exp``, ``sin``,
sorting...) by the CPU it finds; results may differ in the last bits between
those paths. The portable run takes numpy off its AVX-512 paths (the names this
numpy dispatches and this CPU has: ``X86_V4``, ``AVX512_*``); on a CPU without
them, off every dispatched path above numpy's baseline (AVX2 on x86-64), so the
run always differs from the plain ``make test``.
"""

from numpy._core._multiarray_umath import __cpu_dispatch__, __cpu_features__

have = [f for f in __cpu_dispatch__ if __cpu_features__.get(f)]
avx512 = [f for f in have if f.startswith("AVX512") or f == "X86_V4"]
print(" ".join(avx512 or have))
