"""ROS bags without a ROS install (the ``rosbags`` library): :mod:`~skincal.data.ros.reader` imports
a bag as a dataset, :mod:`~skincal.data.ros.writer` writes a dataset as a bag, and
:mod:`~skincal.data.ros.topics` says which topics feed which unit (the topic map)."""

from skincal.data.ros.reader import INTERLEAVED_FRACTION, PROGRESS_EVERY, ImportReport, read_bag
from skincal.data.ros.topics import ROBOT_DESCRIPTION, TopicMap, topic_map
from skincal.data.ros.writer import write_bag

__all__ = [
    "INTERLEAVED_FRACTION",
    "PROGRESS_EVERY",
    "ROBOT_DESCRIPTION",
    "ImportReport",
    "TopicMap",
    "read_bag",
    "topic_map",
    "write_bag",
]
