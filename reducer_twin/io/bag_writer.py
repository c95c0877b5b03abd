"""
Writing rosbag2 bag directories, whole or not at all.

``BagDirWriter`` writes ``<out_dir>/<name>_0.mcap`` and a ``metadata.yaml`` of version 9
as rosbag2 Jazzy does. The directory is an :class:`~reducer_twin.io.outputs.
OutputDir`: the files are written into a temporary sibling and renamed into place when
the bag is complete, so a run that fails or is killed leaves nothing at ``out_dir`` that
looks like a bag; a non-empty ``out_dir`` is replaced only with ``overwrite`` and only
when it holds a bag written by reducer-twin (its ``custom_data`` has ``reducer_twin.*``
keys and it holds nothing but ``metadata.yaml`` and the files it lists); one run at a
time writes a given ``out_dir``; a full disk is one :class:`~reducer_twin.analysis.
outputs.DiskFull` error.

Framing: ``'library'`` (the default, and what ``analyze`` writes) frames the MCAP file
with the mcap library (:class:`~reducer_twin.io.mcap_writer.LibraryMcapWriter`);
``'fast'`` with the project's array writer (:class:`~reducer_twin.io.mcap_array_writer.
McapBagWriter`), which ``simulate`` keeps for its million-message bags.
"""

from pathlib import Path

import numpy as np
from reducer_twin.io.mcap_array_writer import McapBagWriter
from reducer_twin.io.mcap_format import DEFAULT_CHUNK_SIZE
from reducer_twin.io.mcap_writer import LibraryMcapWriter
from reducer_twin.io.outputs import foreign_bag_entries, OUTPUT_KEY_PREFIX, OutputDir
from reducer_twin.io.rosbag2_metadata import bag_metadata, DEFAULT_QOS, dump_yaml
from reducer_twin.msg_adapters.jointstate_cdr import joint_state_columns, MSGTYPE as JOINT_STATE

__all__ = ['BagDirWriter', 'write_bag_dir', 'foreign_bag_entries', 'OUTPUT_KEY_PREFIX']


class BagDirWriter:
    """
    Write a rosbag2 bag directory: ``<name>_0.mcap`` and ``metadata.yaml`` (version 9).

    Parameters
    ----------
    out_dir : str or os.PathLike
        Bag directory; created (with its parents) when complete.
    name : str, optional
        File stem; default the directory name (as ``ros2 bag record -o`` does).
    compression : {'zstd', 'lz4', 'none'}
        MCAP chunk compression.
    chunk_size : int
        Uncompressed bytes per chunk.
    custom_data : dict of str to str, optional
        rosbag2 ``custom_data``; may also be changed through ``custom_data`` until close.
    overwrite : bool
        Replace a bag written by reducer-twin in a non-empty ``out_dir``.
    framing : {'library', 'fast'}
        MCAP framing by the mcap library or by the project's array writer.
    needed : int, optional
        Expected size of the bag [bytes], named when the disk fills up.
    flag : str
        Option name of ``out_dir``, for messages.
    what : str
        What the bag is, for messages (``'derived bag'``, ``'simulated bag'``).

    Raises
    ------
    InvalidParameter
        If ``out_dir`` is a file, is not empty and ``overwrite`` is false, or holds
        files reducer-twin did not write.
    OutputBusy
        If another run writes ``out_dir``.
    BagError
        If the directory cannot be created (``DiskFull`` when the disk is full).

    """

    def __init__(self, out_dir, name=None, compression='zstd', chunk_size=DEFAULT_CHUNK_SIZE,
                 custom_data=None, overwrite=False, framing='library', needed=None,
                 flag='--out', what='bag'):
        if framing not in ('library', 'fast'):
            raise ValueError(f"framing must be 'library' or 'fast', got {framing!r}")
        self.output = OutputDir(out_dir, foreign_bag_entries, what, flag, overwrite, needed,
                                'a bag written by reducer-twin')
        self.out_dir = Path(out_dir)
        self.name = name or self.output.target.name
        self.custom_data = {str(k): str(v) for k, v in (custom_data or {}).items()}
        self.mcap_path = self.out_dir / f'{self.name}_0.mcap'
        tmp = self.output.start()
        try:
            path = tmp / self.mcap_path.name
            if framing == 'library':
                self._writer = LibraryMcapWriter(path, compression=compression,
                                                 chunk_size=chunk_size,
                                                 custom_data=self.custom_data)
            else:
                self._writer = McapBagWriter(path, compression=compression,
                                             chunk_size=chunk_size,
                                             custom_data=self.custom_data)
        except OSError as err:
            self.output.abort()
            raise self.output.error(err) from err
        except BaseException:
            self.output.abort()
            raise
        self._closed = False

    def add_topic(self, name, msgtype, qos=DEFAULT_QOS):
        """
        Declare a topic.

        Parameters
        ----------
        name : str
            Topic name.
        msgtype : str
            ROS type, e.g. ``'sensor_msgs/msg/JointState'``.
        qos : sequence of QosProfile
            Offered QoS profiles.

        Returns
        -------
        int
            Channel id for the write methods.

        """
        return self._guard(self._writer.add_topic, name, msgtype, qos)

    def write(self, channel_id, log_time_ns, data, publish_time_ns=None):
        """
        Write one serialised message.

        Parameters
        ----------
        channel_id : int
            From ``add_topic``.
        log_time_ns : int
            Receive time in ns.
        data : bytes-like
            CDR payload.
        publish_time_ns : int, optional
            Send time in ns.

        """
        self._guard(self._writer.write, channel_id, log_time_ns, data, publish_time_ns)

    def write_batch(self, channel_id, log_times_ns, buffer, offsets, publish_times_ns=None):
        """
        Write N serialised messages held in one buffer.

        Parameters
        ----------
        channel_id : int
            From ``add_topic``.
        log_times_ns : array_like of int
            int64[N] receive times in ns.
        buffer : bytes-like or numpy.ndarray
            Payloads back to back.
        offsets : array_like of int
            int64[N + 1] boundaries.
        publish_times_ns : array_like of int, optional
            int64[N] send times in ns.

        """
        self._guard(self._writer.write_batch, channel_id, log_times_ns, buffer, offsets,
                    publish_times_ns)

    def write_joint_states(self, channel_id, batch, log_times_ns=None):
        """
        Encode and write a JointStateBatch, building the messages in place.

        Parameters
        ----------
        channel_id : int
            From ``add_topic`` (a ``sensor_msgs/msg/JointState`` topic).
        batch : JointStateBatch
            Messages; all-NaN velocity/effort columns are written as empty fields.
        log_times_ns : array_like of int, optional
            Receive times; default ``batch.log_time_ns`` or else the header stamps.

        Raises
        ------
        InvalidInput
            On arrays of the wrong shape or stamps outside the int32 seconds range.

        """
        logs = log_times_ns if log_times_ns is not None else batch.log_time_ns
        logs = np.asarray(batch.stamps_ns if logs is None else logs, np.int64)
        fields = [None if values.size and np.isnan(values).all() else values
                  for values in (batch.position, batch.velocity, batch.effort)]
        template, columns = joint_state_columns(batch.stamps_ns, batch.names, *fields,
                                                frame_id=batch.frame_id)
        self._guard(self._writer.write_template_batch, channel_id, logs, template, columns)

    def start_writeback(self):
        """
        Let the kernel start writing out what was written so far.

        A hint (:func:`~reducer_twin.io.outputs.start_writeback`): the ``fsync`` of
        :meth:`close` then has less to wait for. Only the library writer takes it.
        """
        if isinstance(self._writer, LibraryMcapWriter):
            self._guard(self._writer.start_writeback)

    def close(self):
        """
        Finish the MCAP file, write ``metadata.yaml`` and put the bag in place.

        Returns
        -------
        pathlib.Path
            The bag directory.

        Raises
        ------
        BagError
            If the bag cannot be finished (``DiskFull`` when the disk is full); then
            nothing is left at the bag directory.

        """
        if self._closed:
            return self.out_dir
        try:
            self._writer.set_custom_data(self.custom_data)
            summary = self._guard(self._writer.close)
            info = bag_metadata(self._writer.topic_summaries(), [summary], self.custom_data)
            text = dump_yaml({'rosbag2_bagfile_information': info})
            self._guard((self.output.tmp / 'metadata.yaml').write_text, text,
                        encoding='utf-8')
        except BaseException:
            self.abort()
            raise
        self._closed = True
        self.output.commit()
        return self.out_dir

    def abort(self):
        """Give the bag up: nothing is left at the bag directory."""
        if self._closed:
            return
        self._closed = True
        self._writer.discard()
        self.output.abort()

    def __enter__(self):
        """Return the writer."""
        return self

    def __exit__(self, exc_type, exc, tb):
        """Put the complete bag in place; after an error, leave nothing at the directory."""
        if exc_type is None:
            self.close()
        else:
            self.abort()

    def _guard(self, func, *args, **kwargs):
        """Call a write; turn an OSError into the project's error, leaving nothing behind."""
        try:
            return func(*args, **kwargs)
        except OSError as err:
            self.abort()
            raise self.output.error(err) from err


def write_bag_dir(out_dir, joint_states, custom_data=None, compression='zstd',
                  overwrite=False, qos=DEFAULT_QOS, framing='library'):
    """
    Write JointState batches into a new rosbag2 bag directory.

    Parameters
    ----------
    out_dir : str or os.PathLike
        Bag directory to create.
    joint_states : dict of str to JointStateBatch
        Topic name to messages; log times from ``log_time_ns`` or the header stamps.
    custom_data : dict of str to str, optional
        rosbag2 ``custom_data`` (e.g. the simulator's parameters).
    compression : {'zstd', 'lz4', 'none'}
        MCAP chunk compression.
    overwrite : bool
        Replace a bag written by reducer-twin in ``out_dir``.
    qos : sequence of QosProfile
        Offered QoS of every topic.
    framing : {'library', 'fast'}
        MCAP framing (see :class:`BagDirWriter`).

    Returns
    -------
    pathlib.Path
        The bag directory.

    """
    with BagDirWriter(out_dir, compression=compression, custom_data=custom_data,
                      overwrite=overwrite, framing=framing) as writer:
        for topic, batch in joint_states.items():
            channel = writer.add_topic(topic, JOINT_STATE, qos)
            writer.write_joint_states(channel, batch)
    return writer.out_dir
