"""Data in and out of capataz: the project's one file-I/O package (like evo's ``tools``).

Readers are typed value objects that open one recording and yield the estimator's own measurement types
(:mod:`common.estimation.coupling`) in stamp order; writers turn estimates into files other tools read.

| module          | reads / writes                                                   | error           |
| --------------- | ---------------------------------------------------------------- | --------------- |
| ``images``      | a folder of images, natural sort, optional stamps file           | ImageFolderError|
| ``euroc``       | a EuRoC folder (``mav0/cam0``, ``imu0``, ground truth)           | EurocError      |
| ``rosbag``      | ROS 1 bags, ROS 2 bags (MCAP or sqlite3) via ``rosbags``         | BagError        |
| ``tum``         | TUM trajectories (``timestamp tx ty tz qx qy qz qw``)            | TumError        |
| ``recording``   | capataz's own MCAP recordings (``capataz record``)               | RecordingError  |

Every error derives from :class:`common.errors.InputError`: the CLI prints it as one line, exit code 1.
"""
