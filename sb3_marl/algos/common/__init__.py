"""What the learners share (as sb3-contrib's ``common/maskable``): the base of the maskable
learners (:mod:`~sb3_marl.algos.common.base`), per-agent buffers, the safety teacher and the rule
prior (loss terms), the MA2C network and the centralised critic (:mod:`~sb3_marl.algos.common.policies`),
K-FAC (ACKTR's optimiser) and the model loader that never unpickles (:mod:`~sb3_marl.algos.common.loading`)."""
