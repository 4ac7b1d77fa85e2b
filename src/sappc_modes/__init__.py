"""Flight modes (issue 49): flight software that decides, sample by sample, which mode the
spacecraft flies (DETUMBLE, HOLD, TRACK, SAFE) from its measurements and its estimator's health.
``core``: the compiled transition kernel (:mod:`sappc_modes.core.modes`).  Never imports the
simulator, the controller or the estimator: it reads what they publish."""
