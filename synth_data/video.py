"""The camera's output encoding: video codec, then JPEG (one parameter set, one code path).

Real dense-crowd footage reaches a tracker through a video codec at a modest bit rate, not as
near-lossless stills. :func:`encode_output` is the one code path from rendered frames to the
JPEG files a tracker reads, used by ``generate``'s writer and by in-memory episodes alike: the
frames go through the codec of :class:`crowdsim.appearance_model.Encoding` when its bit rate is
above 0 (:class:`VideoEncoder` writes the MP4, :func:`decode_frames` reads it back through
OpenCV, exactly as :meth:`synth_data.mot.MotSequence.frames` reads a video-only sequence), then
through JPEG at its quality. The ``img1/`` JPEGs therefore carry the same codec artefacts as
``video.mp4``, and :func:`camera_output` gives in memory the frames a tracker reads from disk.

Codecs: OpenCV's pip wheels carry no H.264 *encoder* (``VideoWriter`` with ``avc1``/``H264``
fails to open: the FFmpeg they bundle is built without libx264), and OpenCV's ``mp4v`` writer
takes no bit rate. Both codecs therefore go through PyAV (``pip install av``; its wheels
bundle FFmpeg with libx264): ``"h264"`` (libx264, preset ``veryfast``, constant bit rate
target) and ``"mpeg4"`` (MPEG-4 part 2, the codec of OpenCV's ``mp4v``). OpenCV decodes both.
Encoding is deterministic: libx264 and FFmpeg's mpeg4 encoder give the same bytes for the same
frames and settings, and the MP4 muxer is told to write bit-exact headers. For libx264 that
takes one thread and :data:`X264_PARAMS` (macroblock-tree rate control off): with it on, some
frame sizes (the calibrated ucf9 seq9's 166x334, for one) gave different bits on every run --
x264's SIMD code then reads memory it never initialised (the same run with ``asm=0`` is
deterministic).
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any, BinaryIO

import numpy as np

if TYPE_CHECKING:
    from crowdsim.appearance_model import Encoding

ENCODERS: dict[str, str] = {"h264": "libx264", "mpeg4": "mpeg4"}
"""``appearance.video_codec`` -> FFmpeg encoder name."""
X264_PRESET: str = "veryfast"
"""libx264 speed preset (surveillance encoders trade quality for speed the same way)."""
GOP_SECONDS: float = 2.0
"""Key-frame interval, seconds."""
X264_PARAMS: str = "mbtree=0"
"""libx264 settings beyond the preset: no macroblock-tree rate control (see the module
docstring: with it, the bits of some frame sizes vary from run to run)."""
ENCODER_THREADS: int = 1
"""Encoder threads: x264's output depends on its thread count, so one thread keeps the bytes
the same on every machine (checksums) at about 40 frames/s for 720p."""
DECODER_THREADS: int = 1
"""Decoder threads: one core per sequence (sequences already run in parallel)."""


def _require_av() -> Any:
    """PyAV, a core dependency, imported on first use (it loads FFmpeg's libraries)."""
    import av

    return av


def encoder_available(codec: str) -> bool:
    """Whether ``codec`` (``"h264"`` or ``"mpeg4"``) can be encoded here (PyAV present)."""
    if codec not in ENCODERS:
        raise ValueError(f"video_codec must be one of {tuple(ENCODERS)}, got {codec!r}")
    try:
        av = _require_av()
        av.codec.Codec(ENCODERS[codec], "w")
    except Exception:  # noqa: BLE001 - any failure means "not available"
        return False
    return True


class VideoEncoder:
    """Write ``(H, W, 3)`` uint8 BGR frames to an MP4 file at ``kbps`` kbit/s.

    Parameters
    ----------
    path : path or binary file object
        MP4 file to write (replaced), or a seekable stream such as ``io.BytesIO``.
    width, height : int
        Frame size; odd sizes are not supported by 4:2:0 video and raise ``ValueError``.
    fps : float
        Frame rate.
    kbps : float
        Target bit rate, kbit/s (> 0).
    codec : str
        ``"h264"`` or ``"mpeg4"``.

    Use as a context manager; :meth:`close` flushes the encoder.
    """

    def __init__(
        self,
        path: str | os.PathLike[str] | BinaryIO,
        width: int,
        height: int,
        fps: float,
        kbps: float,
        codec: str = "h264",
    ) -> None:
        from fractions import Fraction

        if codec not in ENCODERS:
            raise ValueError(f"video_codec must be one of {tuple(ENCODERS)}, got {codec!r}")
        if not kbps > 0:
            raise ValueError(f"video_kbps must be > 0, got {kbps!r}")
        if width % 2 or height % 2:
            raise ValueError(f"video frames need even sizes, got {width}x{height}")
        av = _require_av()
        self._av = av
        self.path = path if hasattr(path, "write") else Path(path)
        target = self.path if hasattr(path, "write") else str(self.path)
        self._container = av.open(target, "w", format="mp4", options={"fflags": "+bitexact"})
        rate = Fraction(float(fps)).limit_denominator(1001)
        stream = self._container.add_stream(ENCODERS[codec], rate=rate)
        stream.width, stream.height = int(width), int(height)
        stream.pix_fmt = "yuv420p"
        stream.bit_rate = int(round(kbps * 1000))
        stream.codec_context.gop_size = max(1, int(round(GOP_SECONDS * fps)))
        stream.codec_context.flags |= int(av.codec.context.Flags.bitexact)
        stream.codec_context.thread_count = ENCODER_THREADS
        if codec == "h264":
            stream.options = {"preset": X264_PRESET, "x264-params": X264_PARAMS}
        self._stream = stream
        self.frames = 0

    def write(self, frame: np.ndarray) -> None:
        """Encode one ``(H, W, 3)`` uint8 BGR frame."""
        vf = self._av.VideoFrame.from_ndarray(np.ascontiguousarray(frame), format="bgr24")
        for packet in self._stream.encode(vf):
            self._container.mux(packet)
        self.frames += 1

    def close(self) -> None:
        """Flush the encoder and close the file (idempotent)."""
        if self._container is None:
            return
        try:
            for packet in self._stream.encode():
                self._container.mux(packet)
        finally:
            self._container.close()
            self._container = None

    def __enter__(self) -> VideoEncoder:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


def decode_frames(
    source: str | os.PathLike[str] | BinaryIO, n_frames: int | None = None
) -> Iterator[np.ndarray]:
    """Yield the ``(H, W, 3)`` uint8 BGR frames of an MP4 file or in-memory stream, by OpenCV.

    ``source`` is a path or a binary stream (``io.BytesIO``: OpenCV's stream API); the same
    decoder reads both, so a sequence decoded from memory equals the one read back from disk
    to the byte. With ``n_frames``, exactly that many frames must decode (``ValueError``
    naming the frame otherwise); without it, every frame is yielded.
    """
    import cv2

    params = [cv2.CAP_PROP_N_THREADS, DECODER_THREADS]
    if isinstance(source, (str, os.PathLike)):
        cap = cv2.VideoCapture(str(source), cv2.CAP_FFMPEG, params)
        name = str(source)
    else:
        source.seek(0)
        cap = cv2.VideoCapture(source, cv2.CAP_FFMPEG, params)
        name = "the encoded stream"
    try:
        i = 0
        while n_frames is None or i < n_frames:
            ok, img = cap.read()
            if not ok:
                if n_frames is None:
                    return
                raise ValueError(f"{name}: could not decode frame {i + 1}")
            i += 1
            yield img
    finally:
        cap.release()


def encode_video(
    frames: Iterable[np.ndarray],
    fps: float,
    encoding: Encoding,
    into: str | os.PathLike[str] | BinaryIO,
) -> int:
    """Encode ``frames`` through ``encoding``'s codec at its bit rate into ``into`` (an MP4 path
    or a seekable binary stream); returns the number of frames encoded."""
    enc = None
    try:
        for frame in frames:
            if enc is None:
                h, w = frame.shape[:2]
                enc = VideoEncoder(into, w, h, fps, encoding.video_kbps, encoding.video_codec)
            enc.write(frame)
    finally:
        if enc is not None:
            enc.close()
    return 0 if enc is None else enc.frames


def codec_frames(
    frames: Iterable[np.ndarray],
    fps: float,
    encoding: Encoding,
    into: str | os.PathLike[str] | BinaryIO | None = None,
) -> Iterator[np.ndarray]:
    """The frames after the video codec: the first step of the output encoding.

    With ``encoding.video_kbps > 0`` every frame is encoded (:func:`encode_video`) into
    ``into`` -- the sequence's ``video.mp4``, or an ``io.BytesIO`` when ``None``, so only the
    compressed stream is held -- and decoded back by OpenCV (:func:`decode_frames`). All frames
    are encoded before the first comes out. With ``video_kbps == 0`` the frames pass unchanged.
    """
    if encoding.video_kbps <= 0:
        yield from frames
        return
    if into is None:
        import io

        into = io.BytesIO()
    n = encode_video(frames, fps, encoding, into)
    yield from decode_frames(into, n)


def jpeg_bytes(frames: Iterable[np.ndarray], quality: int) -> Iterator[bytes]:
    """The JPEG file of every frame at ``quality``: the second step of the output encoding."""
    from crowdsim.render import encode_jpeg

    for frame in frames:
        yield encode_jpeg(frame, quality)


def encode_output(
    frames: Iterable[np.ndarray],
    fps: float,
    encoding: Encoding,
    video: str | os.PathLike[str] | BinaryIO | None = None,
) -> Iterator[bytes]:
    """The one code path of the camera's output encoding: codec (if any), then JPEG.

    Yields the ``img1/`` JPEG file of every frame. ``generate``'s writer stores them (and passes
    ``video``, its ``video.mp4``, to keep the coded stream); in-memory sequences decode them
    (:func:`camera_output`). Both therefore see the same bytes.
    """
    yield from jpeg_bytes(codec_frames(frames, fps, encoding, video), encoding.jpeg_quality)


def camera_output(
    frames: Iterable[np.ndarray], fps: float, encoding: Encoding
) -> Iterator[np.ndarray]:
    """The frames a tracker reads from ``generate``'s ``img1/`` JPEGs, made in memory.

    :func:`encode_output`, then each JPEG decoded by OpenCV as ``cv2.imread`` decodes the
    file: the frames equal those of the generated folder exactly, codec or not (tested).
    """
    import cv2

    for data in encode_output(frames, fps, encoding):
        yield cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
