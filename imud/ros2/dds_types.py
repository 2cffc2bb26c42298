"""sensor_msgs Imu, MagneticField and Temperature, and diagnostic_msgs DiagnosticArray, as the DDS
types ROS 2 names them (`<pkg>::msg::dds_::<Type>_`, final, from the .msg definitions), for
Cyclone DDS.

Imported only by the `dds` profile, with cyclonedds installed. No `from __future__ import
annotations`: cyclonedds reads these annotations as types at class creation.
"""

from dataclasses import dataclass

from cyclonedds.idl import IdlStruct
from cyclonedds.idl.annotations import extensibility
from cyclonedds.idl.types import array, byte, float64, int32, sequence, uint32

Cov = array[float64, 9]  # type: ignore[type-arg,valid-type]  # a row-major 3x3 covariance


@extensibility("final")
@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32
    nanosec: uint32


@extensibility("final")
@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time
    frame_id: str


@extensibility("final")
@dataclass
class Quaternion(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    x: float64
    y: float64
    z: float64
    w: float64


@extensibility("final")
@dataclass
class Vector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: float64
    y: float64
    z: float64


@extensibility("final")
@dataclass
class Imu(IdlStruct, typename="sensor_msgs::msg::dds_::Imu_"):
    header: Header
    orientation: Quaternion
    orientation_covariance: Cov
    angular_velocity: Vector3
    angular_velocity_covariance: Cov
    linear_acceleration: Vector3
    linear_acceleration_covariance: Cov


@extensibility("final")
@dataclass
class MagneticField(IdlStruct, typename="sensor_msgs::msg::dds_::MagneticField_"):
    header: Header
    magnetic_field: Vector3
    magnetic_field_covariance: Cov


@extensibility("final")
@dataclass
class Temperature(IdlStruct, typename="sensor_msgs::msg::dds_::Temperature_"):
    header: Header
    temperature: float64
    variance: float64


@extensibility("final")
@dataclass
class KeyValue(IdlStruct, typename="diagnostic_msgs::msg::dds_::KeyValue_"):
    key: str
    value: str


@extensibility("final")
@dataclass
class DiagnosticStatus(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticStatus_"):
    level: byte
    name: str
    message: str
    hardware_id: str
    values: sequence[KeyValue]  # type: ignore[type-arg]


@extensibility("final")
@dataclass
class DiagnosticArray(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticArray_"):
    header: Header
    status: sequence[DiagnosticStatus]  # type: ignore[type-arg]
