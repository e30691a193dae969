"""The stages of a scenario's run, one module each, each a function ``(store, scenario,
upstream records) -> record`` (`vitaplace.engine.pipeline.store`): simulate, fit,
transform, evaluate, fuse (the late fusions), compare (what is read across evaluations),
report. `vitaplace.engine.pipeline.orchestrate.run_stages` sequences them."""
