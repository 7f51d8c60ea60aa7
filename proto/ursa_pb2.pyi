from google.protobuf.internal import containers as _containers
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Iterable as _Iterable, Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class Array(_message.Message):
    __slots__ = ("dtype", "shape", "data")
    DTYPE_FIELD_NUMBER: _ClassVar[int]
    SHAPE_FIELD_NUMBER: _ClassVar[int]
    DATA_FIELD_NUMBER: _ClassVar[int]
    dtype: str
    shape: _containers.RepeatedScalarFieldContainer[int]
    data: bytes
    def __init__(self, dtype: _Optional[str] = ..., shape: _Optional[_Iterable[int]] = ..., data: _Optional[bytes] = ...) -> None: ...

class Header(_message.Message):
    __slots__ = ("schema_version", "run_id", "stamp", "sender")
    SCHEMA_VERSION_FIELD_NUMBER: _ClassVar[int]
    RUN_ID_FIELD_NUMBER: _ClassVar[int]
    STAMP_FIELD_NUMBER: _ClassVar[int]
    SENDER_FIELD_NUMBER: _ClassVar[int]
    schema_version: int
    run_id: str
    stamp: float
    sender: str
    def __init__(self, schema_version: _Optional[int] = ..., run_id: _Optional[str] = ..., stamp: _Optional[float] = ..., sender: _Optional[str] = ...) -> None: ...

class TransitionChunk(_message.Message):
    __slots__ = ("header", "collector_id", "seq", "first_step", "policy_version", "incarnation", "obs", "action", "reward", "cost", "safe", "features", "skill", "task", "damage", "base_pose", "stamp")
    HEADER_FIELD_NUMBER: _ClassVar[int]
    COLLECTOR_ID_FIELD_NUMBER: _ClassVar[int]
    SEQ_FIELD_NUMBER: _ClassVar[int]
    FIRST_STEP_FIELD_NUMBER: _ClassVar[int]
    POLICY_VERSION_FIELD_NUMBER: _ClassVar[int]
    INCARNATION_FIELD_NUMBER: _ClassVar[int]
    OBS_FIELD_NUMBER: _ClassVar[int]
    ACTION_FIELD_NUMBER: _ClassVar[int]
    REWARD_FIELD_NUMBER: _ClassVar[int]
    COST_FIELD_NUMBER: _ClassVar[int]
    SAFE_FIELD_NUMBER: _ClassVar[int]
    FEATURES_FIELD_NUMBER: _ClassVar[int]
    SKILL_FIELD_NUMBER: _ClassVar[int]
    TASK_FIELD_NUMBER: _ClassVar[int]
    DAMAGE_FIELD_NUMBER: _ClassVar[int]
    BASE_POSE_FIELD_NUMBER: _ClassVar[int]
    STAMP_FIELD_NUMBER: _ClassVar[int]
    header: Header
    collector_id: str
    seq: int
    first_step: int
    policy_version: int
    incarnation: int
    obs: Array
    action: Array
    reward: Array
    cost: Array
    safe: Array
    features: Array
    skill: Array
    task: str
    damage: str
    base_pose: Array
    stamp: Array
    def __init__(self, header: _Optional[_Union[Header, _Mapping]] = ..., collector_id: _Optional[str] = ..., seq: _Optional[int] = ..., first_step: _Optional[int] = ..., policy_version: _Optional[int] = ..., incarnation: _Optional[int] = ..., obs: _Optional[_Union[Array, _Mapping]] = ..., action: _Optional[_Union[Array, _Mapping]] = ..., reward: _Optional[_Union[Array, _Mapping]] = ..., cost: _Optional[_Union[Array, _Mapping]] = ..., safe: _Optional[_Union[Array, _Mapping]] = ..., features: _Optional[_Union[Array, _Mapping]] = ..., skill: _Optional[_Union[Array, _Mapping]] = ..., task: _Optional[str] = ..., damage: _Optional[str] = ..., base_pose: _Optional[_Union[Array, _Mapping]] = ..., stamp: _Optional[_Union[Array, _Mapping]] = ...) -> None: ...

class SafeFeatures(_message.Message):
    __slots__ = ("header", "collector_id", "seq", "features")
    HEADER_FIELD_NUMBER: _ClassVar[int]
    COLLECTOR_ID_FIELD_NUMBER: _ClassVar[int]
    SEQ_FIELD_NUMBER: _ClassVar[int]
    FEATURES_FIELD_NUMBER: _ClassVar[int]
    header: Header
    collector_id: str
    seq: int
    features: Array
    def __init__(self, header: _Optional[_Union[Header, _Mapping]] = ..., collector_id: _Optional[str] = ..., seq: _Optional[int] = ..., features: _Optional[_Union[Array, _Mapping]] = ...) -> None: ...

class SkillRequest(_message.Message):
    __slots__ = ("header", "n", "has_seed", "seed")
    HEADER_FIELD_NUMBER: _ClassVar[int]
    N_FIELD_NUMBER: _ClassVar[int]
    HAS_SEED_FIELD_NUMBER: _ClassVar[int]
    SEED_FIELD_NUMBER: _ClassVar[int]
    header: Header
    n: int
    has_seed: bool
    seed: int
    def __init__(self, header: _Optional[_Union[Header, _Mapping]] = ..., n: _Optional[int] = ..., has_seed: _Optional[bool] = ..., seed: _Optional[int] = ...) -> None: ...

class SkillReply(_message.Message):
    __slots__ = ("header", "skills", "delta", "encoder_version", "snapshot_version", "error")
    HEADER_FIELD_NUMBER: _ClassVar[int]
    SKILLS_FIELD_NUMBER: _ClassVar[int]
    DELTA_FIELD_NUMBER: _ClassVar[int]
    ENCODER_VERSION_FIELD_NUMBER: _ClassVar[int]
    SNAPSHOT_VERSION_FIELD_NUMBER: _ClassVar[int]
    ERROR_FIELD_NUMBER: _ClassVar[int]
    header: Header
    skills: Array
    delta: float
    encoder_version: int
    snapshot_version: int
    error: str
    def __init__(self, header: _Optional[_Union[Header, _Mapping]] = ..., skills: _Optional[_Union[Array, _Mapping]] = ..., delta: _Optional[float] = ..., encoder_version: _Optional[int] = ..., snapshot_version: _Optional[int] = ..., error: _Optional[str] = ...) -> None: ...

class RepertoireSnapshot(_message.Message):
    __slots__ = ("header", "version", "skills", "ids", "ages", "nn_dist", "cov", "inputs", "delta", "entropy_bound", "encoder_version", "commits", "capacity", "n_z")
    HEADER_FIELD_NUMBER: _ClassVar[int]
    VERSION_FIELD_NUMBER: _ClassVar[int]
    SKILLS_FIELD_NUMBER: _ClassVar[int]
    IDS_FIELD_NUMBER: _ClassVar[int]
    AGES_FIELD_NUMBER: _ClassVar[int]
    NN_DIST_FIELD_NUMBER: _ClassVar[int]
    COV_FIELD_NUMBER: _ClassVar[int]
    INPUTS_FIELD_NUMBER: _ClassVar[int]
    DELTA_FIELD_NUMBER: _ClassVar[int]
    ENTROPY_BOUND_FIELD_NUMBER: _ClassVar[int]
    ENCODER_VERSION_FIELD_NUMBER: _ClassVar[int]
    COMMITS_FIELD_NUMBER: _ClassVar[int]
    CAPACITY_FIELD_NUMBER: _ClassVar[int]
    N_Z_FIELD_NUMBER: _ClassVar[int]
    header: Header
    version: int
    skills: Array
    ids: Array
    ages: Array
    nn_dist: Array
    cov: Array
    inputs: Array
    delta: float
    entropy_bound: float
    encoder_version: int
    commits: int
    capacity: int
    n_z: int
    def __init__(self, header: _Optional[_Union[Header, _Mapping]] = ..., version: _Optional[int] = ..., skills: _Optional[_Union[Array, _Mapping]] = ..., ids: _Optional[_Union[Array, _Mapping]] = ..., ages: _Optional[_Union[Array, _Mapping]] = ..., nn_dist: _Optional[_Union[Array, _Mapping]] = ..., cov: _Optional[_Union[Array, _Mapping]] = ..., inputs: _Optional[_Union[Array, _Mapping]] = ..., delta: _Optional[float] = ..., entropy_bound: _Optional[float] = ..., encoder_version: _Optional[int] = ..., commits: _Optional[int] = ..., capacity: _Optional[int] = ..., n_z: _Optional[int] = ...) -> None: ...

class PolicyWeights(_message.Message):
    __slots__ = ("header", "version", "safetensors", "config_hash", "updates")
    HEADER_FIELD_NUMBER: _ClassVar[int]
    VERSION_FIELD_NUMBER: _ClassVar[int]
    SAFETENSORS_FIELD_NUMBER: _ClassVar[int]
    CONFIG_HASH_FIELD_NUMBER: _ClassVar[int]
    UPDATES_FIELD_NUMBER: _ClassVar[int]
    header: Header
    version: int
    safetensors: bytes
    config_hash: str
    updates: int
    def __init__(self, header: _Optional[_Union[Header, _Mapping]] = ..., version: _Optional[int] = ..., safetensors: _Optional[bytes] = ..., config_hash: _Optional[str] = ..., updates: _Optional[int] = ...) -> None: ...

class EncoderWeights(_message.Message):
    __slots__ = ("header", "version", "safetensors", "config_hash")
    HEADER_FIELD_NUMBER: _ClassVar[int]
    VERSION_FIELD_NUMBER: _ClassVar[int]
    SAFETENSORS_FIELD_NUMBER: _ClassVar[int]
    CONFIG_HASH_FIELD_NUMBER: _ClassVar[int]
    header: Header
    version: int
    safetensors: bytes
    config_hash: str
    def __init__(self, header: _Optional[_Union[Header, _Mapping]] = ..., version: _Optional[int] = ..., safetensors: _Optional[bytes] = ..., config_hash: _Optional[str] = ...) -> None: ...

class Stats(_message.Message):
    __slots__ = ("header", "service", "id", "scalars", "labels", "arrays")
    class ScalarsEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: float
        def __init__(self, key: _Optional[str] = ..., value: _Optional[float] = ...) -> None: ...
    class LabelsEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: str
        def __init__(self, key: _Optional[str] = ..., value: _Optional[str] = ...) -> None: ...
    class ArraysEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: Array
        def __init__(self, key: _Optional[str] = ..., value: _Optional[_Union[Array, _Mapping]] = ...) -> None: ...
    HEADER_FIELD_NUMBER: _ClassVar[int]
    SERVICE_FIELD_NUMBER: _ClassVar[int]
    ID_FIELD_NUMBER: _ClassVar[int]
    SCALARS_FIELD_NUMBER: _ClassVar[int]
    LABELS_FIELD_NUMBER: _ClassVar[int]
    ARRAYS_FIELD_NUMBER: _ClassVar[int]
    header: Header
    service: str
    id: str
    scalars: _containers.ScalarMap[str, float]
    labels: _containers.ScalarMap[str, str]
    arrays: _containers.MessageMap[str, Array]
    def __init__(self, header: _Optional[_Union[Header, _Mapping]] = ..., service: _Optional[str] = ..., id: _Optional[str] = ..., scalars: _Optional[_Mapping[str, float]] = ..., labels: _Optional[_Mapping[str, str]] = ..., arrays: _Optional[_Mapping[str, Array]] = ...) -> None: ...

class EvaluateRequest(_message.Message):
    __slots__ = ("header", "skill", "steps", "damage", "has_seed", "seed")
    HEADER_FIELD_NUMBER: _ClassVar[int]
    SKILL_FIELD_NUMBER: _ClassVar[int]
    STEPS_FIELD_NUMBER: _ClassVar[int]
    DAMAGE_FIELD_NUMBER: _ClassVar[int]
    HAS_SEED_FIELD_NUMBER: _ClassVar[int]
    SEED_FIELD_NUMBER: _ClassVar[int]
    header: Header
    skill: Array
    steps: int
    damage: str
    has_seed: bool
    seed: int
    def __init__(self, header: _Optional[_Union[Header, _Mapping]] = ..., skill: _Optional[_Union[Array, _Mapping]] = ..., steps: _Optional[int] = ..., damage: _Optional[str] = ..., has_seed: _Optional[bool] = ..., seed: _Optional[int] = ...) -> None: ...

class EvaluateReply(_message.Message):
    __slots__ = ("header", "achieved", "distance", "delta", "ret", "violations", "steps", "policy_version", "error")
    HEADER_FIELD_NUMBER: _ClassVar[int]
    ACHIEVED_FIELD_NUMBER: _ClassVar[int]
    DISTANCE_FIELD_NUMBER: _ClassVar[int]
    DELTA_FIELD_NUMBER: _ClassVar[int]
    RET_FIELD_NUMBER: _ClassVar[int]
    VIOLATIONS_FIELD_NUMBER: _ClassVar[int]
    STEPS_FIELD_NUMBER: _ClassVar[int]
    POLICY_VERSION_FIELD_NUMBER: _ClassVar[int]
    ERROR_FIELD_NUMBER: _ClassVar[int]
    header: Header
    achieved: Array
    distance: float
    delta: float
    ret: float
    violations: int
    steps: int
    policy_version: int
    error: str
    def __init__(self, header: _Optional[_Union[Header, _Mapping]] = ..., achieved: _Optional[_Union[Array, _Mapping]] = ..., distance: _Optional[float] = ..., delta: _Optional[float] = ..., ret: _Optional[float] = ..., violations: _Optional[int] = ..., steps: _Optional[int] = ..., policy_version: _Optional[int] = ..., error: _Optional[str] = ...) -> None: ...

class AdaptRequest(_message.Message):
    __slots__ = ("header", "damage", "frozen_joints", "budget", "alpha", "kappa", "length_scale", "noise", "skills", "steps", "has_seed", "seed")
    HEADER_FIELD_NUMBER: _ClassVar[int]
    DAMAGE_FIELD_NUMBER: _ClassVar[int]
    FROZEN_JOINTS_FIELD_NUMBER: _ClassVar[int]
    BUDGET_FIELD_NUMBER: _ClassVar[int]
    ALPHA_FIELD_NUMBER: _ClassVar[int]
    KAPPA_FIELD_NUMBER: _ClassVar[int]
    LENGTH_SCALE_FIELD_NUMBER: _ClassVar[int]
    NOISE_FIELD_NUMBER: _ClassVar[int]
    SKILLS_FIELD_NUMBER: _ClassVar[int]
    STEPS_FIELD_NUMBER: _ClassVar[int]
    HAS_SEED_FIELD_NUMBER: _ClassVar[int]
    SEED_FIELD_NUMBER: _ClassVar[int]
    header: Header
    damage: str
    frozen_joints: _containers.RepeatedScalarFieldContainer[int]
    budget: int
    alpha: float
    kappa: float
    length_scale: float
    noise: float
    skills: int
    steps: int
    has_seed: bool
    seed: int
    def __init__(self, header: _Optional[_Union[Header, _Mapping]] = ..., damage: _Optional[str] = ..., frozen_joints: _Optional[_Iterable[int]] = ..., budget: _Optional[int] = ..., alpha: _Optional[float] = ..., kappa: _Optional[float] = ..., length_scale: _Optional[float] = ..., noise: _Optional[float] = ..., skills: _Optional[int] = ..., steps: _Optional[int] = ..., has_seed: _Optional[bool] = ..., seed: _Optional[int] = ...) -> None: ...

class AdaptJob(_message.Message):
    __slots__ = ("header", "job_id", "evaluator_id", "state", "stop_reason", "error", "request", "map_skills", "map_ids", "map_returns", "mapped", "map_cached", "trials", "chosen_skill_id", "chosen_return", "predicted_best_id", "predicted_best_mean", "predicted_mean", "predicted_std", "policy_version", "created", "updated")
    class Trial(_message.Message):
        __slots__ = ("row", "skill_id", "skill", "ret", "achieved", "violations", "predicted", "predicted_best_id", "predicted_best_mean")
        ROW_FIELD_NUMBER: _ClassVar[int]
        SKILL_ID_FIELD_NUMBER: _ClassVar[int]
        SKILL_FIELD_NUMBER: _ClassVar[int]
        RET_FIELD_NUMBER: _ClassVar[int]
        ACHIEVED_FIELD_NUMBER: _ClassVar[int]
        VIOLATIONS_FIELD_NUMBER: _ClassVar[int]
        PREDICTED_FIELD_NUMBER: _ClassVar[int]
        PREDICTED_BEST_ID_FIELD_NUMBER: _ClassVar[int]
        PREDICTED_BEST_MEAN_FIELD_NUMBER: _ClassVar[int]
        row: int
        skill_id: int
        skill: Array
        ret: float
        achieved: Array
        violations: int
        predicted: float
        predicted_best_id: int
        predicted_best_mean: float
        def __init__(self, row: _Optional[int] = ..., skill_id: _Optional[int] = ..., skill: _Optional[_Union[Array, _Mapping]] = ..., ret: _Optional[float] = ..., achieved: _Optional[_Union[Array, _Mapping]] = ..., violations: _Optional[int] = ..., predicted: _Optional[float] = ..., predicted_best_id: _Optional[int] = ..., predicted_best_mean: _Optional[float] = ...) -> None: ...
    HEADER_FIELD_NUMBER: _ClassVar[int]
    JOB_ID_FIELD_NUMBER: _ClassVar[int]
    EVALUATOR_ID_FIELD_NUMBER: _ClassVar[int]
    STATE_FIELD_NUMBER: _ClassVar[int]
    STOP_REASON_FIELD_NUMBER: _ClassVar[int]
    ERROR_FIELD_NUMBER: _ClassVar[int]
    REQUEST_FIELD_NUMBER: _ClassVar[int]
    MAP_SKILLS_FIELD_NUMBER: _ClassVar[int]
    MAP_IDS_FIELD_NUMBER: _ClassVar[int]
    MAP_RETURNS_FIELD_NUMBER: _ClassVar[int]
    MAPPED_FIELD_NUMBER: _ClassVar[int]
    MAP_CACHED_FIELD_NUMBER: _ClassVar[int]
    TRIALS_FIELD_NUMBER: _ClassVar[int]
    CHOSEN_SKILL_ID_FIELD_NUMBER: _ClassVar[int]
    CHOSEN_RETURN_FIELD_NUMBER: _ClassVar[int]
    PREDICTED_BEST_ID_FIELD_NUMBER: _ClassVar[int]
    PREDICTED_BEST_MEAN_FIELD_NUMBER: _ClassVar[int]
    PREDICTED_MEAN_FIELD_NUMBER: _ClassVar[int]
    PREDICTED_STD_FIELD_NUMBER: _ClassVar[int]
    POLICY_VERSION_FIELD_NUMBER: _ClassVar[int]
    CREATED_FIELD_NUMBER: _ClassVar[int]
    UPDATED_FIELD_NUMBER: _ClassVar[int]
    header: Header
    job_id: str
    evaluator_id: str
    state: str
    stop_reason: str
    error: str
    request: AdaptRequest
    map_skills: Array
    map_ids: Array
    map_returns: Array
    mapped: int
    map_cached: bool
    trials: _containers.RepeatedCompositeFieldContainer[AdaptJob.Trial]
    chosen_skill_id: int
    chosen_return: float
    predicted_best_id: int
    predicted_best_mean: float
    predicted_mean: Array
    predicted_std: Array
    policy_version: int
    created: float
    updated: float
    def __init__(self, header: _Optional[_Union[Header, _Mapping]] = ..., job_id: _Optional[str] = ..., evaluator_id: _Optional[str] = ..., state: _Optional[str] = ..., stop_reason: _Optional[str] = ..., error: _Optional[str] = ..., request: _Optional[_Union[AdaptRequest, _Mapping]] = ..., map_skills: _Optional[_Union[Array, _Mapping]] = ..., map_ids: _Optional[_Union[Array, _Mapping]] = ..., map_returns: _Optional[_Union[Array, _Mapping]] = ..., mapped: _Optional[int] = ..., map_cached: _Optional[bool] = ..., trials: _Optional[_Iterable[_Union[AdaptJob.Trial, _Mapping]]] = ..., chosen_skill_id: _Optional[int] = ..., chosen_return: _Optional[float] = ..., predicted_best_id: _Optional[int] = ..., predicted_best_mean: _Optional[float] = ..., predicted_mean: _Optional[_Union[Array, _Mapping]] = ..., predicted_std: _Optional[_Union[Array, _Mapping]] = ..., policy_version: _Optional[int] = ..., created: _Optional[float] = ..., updated: _Optional[float] = ...) -> None: ...

class AdaptQuery(_message.Message):
    __slots__ = ("header", "job_id")
    HEADER_FIELD_NUMBER: _ClassVar[int]
    JOB_ID_FIELD_NUMBER: _ClassVar[int]
    header: Header
    job_id: str
    def __init__(self, header: _Optional[_Union[Header, _Mapping]] = ..., job_id: _Optional[str] = ...) -> None: ...
