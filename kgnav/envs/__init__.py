"""Any simulator behind one documented interface (docs/bring-your-own-simulator.md).

* :mod:`kgnav.envs.spec`: what an environment declares (:class:`EnvSpec`: camera, actions,
  class vocabulary);
* :mod:`kgnav.envs.protocol`: the observations and the optional ground truth
  (:class:`NavEnv`, :func:`check_observation`);
* :mod:`kgnav.envs.registry`: environments by name (:func:`register_env`, :func:`make_env`);
  kgnav's own simulator is ``kgnav``;
* :mod:`kgnav.envs.miniworld`: MiniWorld houses as ``miniworld`` (``kgnav[miniworld]``, an
  entry point; MiniWorld itself is imported only when a scene renders).
"""

from kgnav.envs.protocol import (
    GROUND_TRUTH_HOOKS,
    OBSERVATION_KEYS,
    EnvProtocolError,
    NavEnv,
    check_env,
    check_observation,
)
from kgnav.envs.registry import (
    DEFAULT_ENV,
    ENVS,
    EnvOptions,
    EnvSuite,
    env_applies_noise,
    env_names,
    env_weights,
    find_env,
    make_env,
    register_env,
)
from kgnav.envs.spec import ACTION_NAMES, ActionSpec, CameraSpec, EnvSpec, EnvSpecError

__all__ = [
    "ACTION_NAMES",
    "DEFAULT_ENV",
    "ENVS",
    "GROUND_TRUTH_HOOKS",
    "OBSERVATION_KEYS",
    "ActionSpec",
    "CameraSpec",
    "EnvOptions",
    "EnvProtocolError",
    "EnvSpec",
    "EnvSpecError",
    "EnvSuite",
    "NavEnv",
    "check_env",
    "check_observation",
    "env_applies_noise",
    "env_names",
    "env_weights",
    "find_env",
    "make_env",
    "register_env",
]
