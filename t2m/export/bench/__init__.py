"""Speed benchmarks: `t2m bench` (implementations of one GPT) and `t2m bench --bundle` (whole requests on bundles)."""
