"""The encoder's non-learned inputs, computed from a video and its cameras.

``preprocess.prepare_source`` turns a calibrated clip into :class:`source_inputs.SourceInputs` (batched
as ``SourceBatch``): the motion mask M_t from pose-compensated motion isolation (``motion``, with
plane-sweep depth from ``depth`` when the capture has none) and flow-propagated point tracks
(``tracks``).  Numpy and OpenCV, no learned weights; the networks read only ``source_inputs``.

Nothing is imported here, so that importing ``source_inputs`` (as the networks do) loads no OpenCV.
"""
