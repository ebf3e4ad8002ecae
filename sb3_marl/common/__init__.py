"""What every layer uses and nothing of the domain: value checks (:mod:`~sb3_marl.common.checks`),
file readers and the atomic writer (:mod:`~sb3_marl.common.files`), the literal parser of
hyperparameter strings (:mod:`~sb3_marl.common.literals`), the compiled kernel's cache
(:mod:`~sb3_marl.common.compiled`)."""
