"""Bags: the one home of the suite's rosbag2 storage, without ROS.

- :mod:`.writer` writes bags as rosbag2 Jazzy does (MCAP storage, ``metadata.yaml``): the
  recorder's sessions, and recordings saved as bags;
- :mod:`.reader` opens a bag in any accepted form (a folder, one storage file, compressed,
  cut short by a killed recorder) and reads its raw messages;
- :mod:`.metadata` reads what a bag says of itself (its ``custom_data``);
- :mod:`.errors`: one root, :class:`BagError`, with its read, output, exists and write
  kinds.

The recorder (:mod:`hydropump_ctrl.recorder`) and identification
(:mod:`hydropump_ctrl.ident`) both take their bags from here; neither imports the other.
"""

from .errors import BagError, BagExistsError, BagOutputError, BagReadError, BagWriteError
from .metadata import custom_data
from .reader import (
           Bag,
           decode,
           existing,
           header_stamps,
           list_topics,
           match_topic,
           one_line,
           open_bag,
           Stream,
)
from .writer import (
           BagWriter,
           message_definition,
           open_unique,
           qos_profile,
           typestore,
           unique_path,
           write_bag,
)

__all__ = ['Bag', 'BagError', 'BagExistsError', 'BagOutputError', 'BagReadError',
           'BagWriteError', 'BagWriter', 'custom_data', 'decode', 'existing', 'header_stamps',
           'list_topics', 'match_topic', 'message_definition', 'one_line', 'open_bag',
           'open_unique', 'qos_profile', 'Stream', 'typestore', 'unique_path', 'write_bag']
