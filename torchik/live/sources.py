"""A source by its URL: the one place that knows which module reads which scheme."""

from __future__ import annotations

from .sample import BACKLOG, Source, parse_url


def open_source(text: str, rate: float | None = None, timeout: float = 5.0, mvn_position_scale: float = 1.0,
                receiver_process: bool = False, backlog: int | None = None) -> Source:
    """The source a URL names (udp, tcp: an MVN stream; lsl: a Mocap stream), `rate` its frame
    rate when known (else the source finds it). timeout: how long an LSL stream is looked for;
    mvn_position_scale: metres per unit of an MVN stream's positions (`torchik.live.mvn`);
    receiver_process: receive a udp:// stream in a process of its own (`receiver.py`), keeping per
    character at most its newest `backlog` samples (None: `BACKLOG`; TCP and LSL streams are
    received in this process)."""
    url = parse_url(text)
    if url.scheme == "lsl":
        from .lsl import LslSource

        return LslSource(url, rate, timeout)
    if receiver_process and url.scheme == "udp":
        from .receiver import ReceiverProcess

        return ReceiverProcess(url, rate, mvn_position_scale, backlog or BACKLOG)
    from .mvn_source import MvnSource

    return MvnSource(url, rate, position_scale=mvn_position_scale)
