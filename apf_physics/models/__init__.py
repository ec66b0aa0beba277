"""Q-networks, their files, greedy policies, and the models shipped with the package.

- :mod:`~apf_physics.models.network`: the thesis's Q-network and its observation transforms.
- :mod:`~apf_physics.models.files`: self-describing, checksummed model and checkpoint files.
- :mod:`~apf_physics.models.policy`: a loaded network as a greedy policy over observations.

The shipped models (``*.pt`` beside this file; ``README.md`` says how each was trained and
how to regenerate it) are found by the field they were trained for with
:func:`shipped_model_for`.
"""

from __future__ import annotations

from pathlib import Path

from apf_physics.errors import ModelError
from apf_physics.models.files import FORMAT_VERSION, SavedModel, load_model, model_meta, save_model
from apf_physics.models.network import QNetwork
from apf_physics.models.mapnet import MapNetwork
from apf_physics.models.policy import DQNPolicy, MapPolicy, load_policy
from apf_physics.world.core import World

MODELS = Path(__file__).resolve().parent
SHIPPED = {"thesis-fixed": MODELS / "fixed20.pt", "thesis-general": MODELS / "map.pt"}
"""The default learned planner's model (planner ``dqn``), by the world's field preset: the fixed world's Q-network
for Table 3's field; the map network (which generalises to rooms, mazes and bigger maps) for
Table 4's. The other shipped files (``general.pt``, ``moving.pt``) are chosen by name."""


def resolve_model(model: str | Path) -> Path:
    """A model file: a path, or the name of a shipped model (``general``, ``moving``: the
    ``.pt`` files beside this module) when no such path exists."""
    path = Path(model)
    if not path.exists() and path.parent == Path(".") and (MODELS / f"{path.stem}.pt").is_file():
        return MODELS / f"{path.stem}.pt"
    return path


SHIPPED_FORMATION = {"thesis-general": MODELS / "general.pt"}
"""Where it differs, the default model for the leader of a formation (a world with ``formation``,
e.g. one of several formations crossing): the window network, which sees the other formations'
robots in its window, rather than the map network, whose values are those of the static map and
leave meeting robots to the right of way. Chosen on a validation set of crossing formations
(``generate --family crossing --count 60 --seed 8``): every formation arrived in 60/60 worlds
with ``general.pt`` leaders, 56/60 with ``map.pt``. A lone formation on Table 4's field (no other
robots to see) gets it too, as a leader: that case was not compared."""


SHIPPED_NETWORKS = {
    "window": {"thesis-fixed": MODELS / "fixed20.pt", "thesis-general": MODELS / "general.pt"},
    "map": {"thesis-general": MODELS / "map.pt"},
}
"""The shipped models of each kind of network, by the field they were trained in: the thesis's
window Q-network (planner ``window-dqn``) and the map network (planner ``mapnet``)."""
NETWORKS = {"window": "the window Q-network (the thesis's DQN)", "map": "the map network"}
"""What each kind of network is called in messages."""


def shipped_model_for(world: World, network: str | None = None) -> Path:
    """The shipped model whose training field equals the world's field: the best of any kind
    (:data:`SHIPPED`; for a formation's leader :data:`SHIPPED_FORMATION` first), or of the kind
    ``network`` (``"window"`` or ``"map"``, :data:`SHIPPED_NETWORKS`).

    Raises:
        ModelError: No shipped model (of that kind) was trained for this field.
    """
    if network is not None:
        for preset, path in SHIPPED_NETWORKS[network].items():
            if world.field.equals_preset(preset) and path.exists():
                return path
        raise ModelError(f"{world.label}: no shipped {NETWORKS[network]} for its field {world.field.as_dict()}; "
                         f"train one with `apf-physics train` and pass --model")
    table = {**SHIPPED, **SHIPPED_FORMATION} if world.formation is not None else SHIPPED
    for preset, path in table.items():
        if world.field.equals_preset(preset) and path.exists():
            return path
    raise ModelError(f"{world.label}: no shipped model for its field {world.field.as_dict()}; "
                     f"train one with `apf-physics train` and pass --model")


__all__ = ["resolve_model", "DQNPolicy", "MapNetwork", "MapPolicy", "load_policy", "FORMAT_VERSION", "MODELS", "NETWORKS", "QNetwork", "SHIPPED", "SHIPPED_FORMATION", "SHIPPED_NETWORKS", "SavedModel", "load_model", "model_meta",
           "save_model", "shipped_model_for"]
