"""The bus contract (version 1) as code: messages, key expressions, codec. Stdlib + msgpack only.

Typical use::

    from bus_schemas import Pose, decode, encode, DecodeError, keys

    payload = encode(Pose(t=now_s, seq=n, x=0.1, y=0.2, theta=0.0))
    session.put(keys.pose_key("demo", "r1"), payload)
    ...
    msg = decode(sample_bytes, Pose)
    if isinstance(msg, DecodeError):
        rejected += 1          # msg.reason, msg.detail, msg.field say why
    else:
        use(msg.x, msg.y, msg.theta)

docs/bus.md is rendered from the same tables (`python -m bus_schemas.docs`).
"""

from bus_schemas import keys
from bus_schemas.codec import (
    decode,
    decode_estop_answer,
    decode_or_raise,
    encode,
    encode_estop_entries,
    from_map,
    to_map,
    validate,
)
from bus_schemas.errors import DecodeError, Reason, RejectCounts, SchemaError
from bus_schemas.messages import (
    BATCH_CHUNK,
    ESTOP_ID_MAX,
    MESSAGE_TYPES,
    Assignment,
    CameraStatus,
    Clock,
    CmdVel,
    CoordinatorStatus,
    Disturbance,
    DisturbanceKind,
    Estop,
    Goal,
    Heartbeat,
    Leader,
    LeaderMode,
    Message,
    Movers,
    Obstacle,
    Path,
    PlantStatus,
    Pose,
    PoseBatch,
    ReshapeSource,
    Role,
    Setpoint,
    SetpointBatch,
    Shape,
    ShapeKind,
    Slot,
    Status,
    StatusBatch,
    Truth,
    TruthBatch,
    Wheels,
    WheelsBatch,
    message_type,
    message_type_for_key,
    new_estop_id,
)
from bus_schemas.messages_fault import Fault, FaultKind
from bus_schemas.messages_operator import ObstacleAction, ObstacleShape
from bus_schemas.messages_status import (
    CAMERA_MS_MAX,
    CameraState,
    CoordinatorRole,
    EstopStoreState,
    PlanState,
    PlantState,
    RunMode,
)
from bus_schemas.modes import Mode
from bus_schemas.spec import (
    MAX_LIST_LEN,
    MAX_MAP_LEN,
    MAX_PAYLOAD_BYTES,
    MAX_STR_LEN,
    VERSION,
    MessageSpec,
    spec_of,
)

__all__ = [
    "BATCH_CHUNK",
    "CAMERA_MS_MAX",
    "ESTOP_ID_MAX",
    "MAX_LIST_LEN",
    "MAX_MAP_LEN",
    "MAX_PAYLOAD_BYTES",
    "MAX_STR_LEN",
    "MESSAGE_TYPES",
    "VERSION",
    "Assignment",
    "CameraState",
    "CameraStatus",
    "Clock",
    "CmdVel",
    "CoordinatorRole",
    "CoordinatorStatus",
    "DecodeError",
    "Disturbance",
    "DisturbanceKind",
    "Estop",
    "EstopStoreState",
    "Fault",
    "FaultKind",
    "Goal",
    "Heartbeat",
    "Leader",
    "LeaderMode",
    "Message",
    "MessageSpec",
    "Mode",
    "Movers",
    "Obstacle",
    "ObstacleAction",
    "ObstacleShape",
    "Path",
    "PlanState",
    "PlantState",
    "PlantStatus",
    "Pose",
    "PoseBatch",
    "Reason",
    "RejectCounts",
    "ReshapeSource",
    "Role",
    "RunMode",
    "SchemaError",
    "Setpoint",
    "SetpointBatch",
    "Shape",
    "ShapeKind",
    "Slot",
    "Status",
    "StatusBatch",
    "Truth",
    "TruthBatch",
    "Wheels",
    "WheelsBatch",
    "decode",
    "decode_estop_answer",
    "decode_or_raise",
    "encode",
    "encode_estop_entries",
    "from_map",
    "keys",
    "message_type",
    "message_type_for_key",
    "new_estop_id",
    "spec_of",
    "to_map",
    "validate",
]
