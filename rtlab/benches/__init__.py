"""Benchmarks behind `rtlab bench ...` that need more than rtlab.benches.primary.bench_render: one module per
table of the paper or per suite (intersect: Table 3; robustness: the stiff and extreme cases)."""
