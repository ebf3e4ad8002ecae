"""The authors' priority-based safety supervisor (:mod:`~sb3_marl.safety.supervisor`) and the
predicted safety rooms it decides by (:mod:`~sb3_marl.safety.rooms`); built on :mod:`sb3_marl.sim`
only (the scenarios configure it)."""
