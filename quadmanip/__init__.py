"""quadmanip: a quadruped robot with an arm that tidies a house.

The installed package maps the repository's top-level folders:
``quadmanip.common`` (messages, bus, config, runtime), ``quadmanip.services``
(one folder per service), ``quadmanip.sim`` (MuJoCo world and sim service) and
``quadmanip.configs`` (TOML parameters, robot description, object catalogue).
"""

__version__ = "0.1.0"
