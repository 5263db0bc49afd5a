"""Calibration: the cameras' and the projector's models, their files, and how they are fitted.

Modules, in the order the data flows through them:

- :mod:`~nail2nail.calibration.camera_models`: pinhole cameras (OpenCV intrinsics and lens
  distortion), DLT matrices and the conversions between them;
- :mod:`~nail2nail.calibration.distortion`: the projector's radial distortion (thesis
  eq. 3.15–3.42): the model, the look-up-table correction of the patterns, its estimation;
- :mod:`~nail2nail.calibration.files`: a rig's calibration (:class:`RigCalibration`) and its
  JSON file form; :mod:`~nail2nail.calibration.opencv_files`: OpenCV's calibration files;
- :mod:`~nail2nail.calibration.boards`: printed flat boards (checkerboard, ChArUco, circles),
  rendering and detection; :mod:`~nail2nail.calibration.markers`: the thesis's cylindrical
  target and its reference marks;
- :mod:`~nail2nail.calibration.observe`: board and target observations from decoded captures;
- :mod:`~nail2nail.calibration.dlt`: least-squares (DLT) projection matrices (thesis
  eq. 3.1–3.11), the point-table calibration and its cross-check;
- :mod:`~nail2nail.calibration.target`: joint refinement of pinhole cameras and one projector
  on the cylindrical target;
- :mod:`~nail2nail.calibration.board`: cameras and projector from a flat board in several poses
  (Zhang's method, local homographies, one bundle adjustment).

The first three are models and files that the scan stage (:mod:`nail2nail.scan`) reads; the
others fit them and themselves decode and triangulate with :mod:`nail2nail.scan`. So this
package re-exports nothing: import from its modules
(``from nail2nail.calibration.dlt import calibrate_points``), which keeps the scan stage free
of the fitting code.
"""
