"""The models the benchmark trains and runs: the physics step (:mod:`~nanosysid.models.physics`),
the learned sequence model and its checkpoints (:mod:`~nanosysid.models.learned`), its
networks (:mod:`~nanosysid.models.components`) and its training
(:mod:`~nanosysid.models.training`). The registry of predictor kinds is
:mod:`nanosysid.predictors`, above this package."""
