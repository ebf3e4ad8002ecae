"""Training runs: hyperparameters from the zoo configs (:mod:`~sb3_marl.runs.hyperparams`), the
VecEnv and model builders (:mod:`~sb3_marl.runs.training`), the run specification and its folders
(:mod:`~sb3_marl.runs.folders`), the experiment manager (:mod:`~sb3_marl.runs.experiment`), the
callbacks and Optuna tuning."""
