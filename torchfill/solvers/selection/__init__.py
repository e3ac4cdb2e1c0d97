"""The parts of the default's per-gap choice (:mod:`torchfill.solvers.auto`): the candidates and
their fits (:mod:`.candidates`), the hold-out draws (:mod:`.draws`), gap kinds (:mod:`.kinds`),
per-kind weights and their combination (:mod:`.weights`), the error model
(:mod:`.error_model`) and the cross-trial hold-out (:mod:`.cross`). Measurements behind each
choice: experiments/results/auto.md and docs/real-gaps.md."""
