"""The hostile-input corpus (no 5xx from any input): named requests exactly as they go on the wire.

A case is data: the bytes sent, how they are sent (in pieces, `gap_s` apart: a slow client), and what the answer
must be beyond the rules every case obeys (tests/fuzz/hostile_check.py: an answer below 500; an error body that is
UTF-8 JSON with a `detail`). To add one, append a `Case` to the list it belongs to; `generate()` and `request()` build
the bytes. The server runs with the settings of `SERVER_ENV` (short request deadlines, an API key), so the timed
cases are answered 408 within seconds.
"""
from __future__ import annotations

import json
from dataclasses import dataclass

__all__ = ["API_KEY", "CASES", "HEADER_TIMEOUT_S", "SERVER_ENV", "Case", "generate", "request"]

API_KEY = "hostile-corpus-key"
HEADER_TIMEOUT_S = 2.0
BODY_TIMEOUT_S = 2.0
SERVER_ENV = {"T2M_API_KEY": API_KEY, "T2M_HEADER_TIMEOUT_S": str(HEADER_TIMEOUT_S),
              "T2M_BODY_TIMEOUT_S": str(BODY_TIMEOUT_S), "T2M_MAX_QUEUE": "64", "T2M_BATCH_WINDOW_MS": "0"}
MAX_BODY_BYTES = 64 * 1024   # the server's default T2M_MAX_BODY_BYTES


@dataclass(frozen=True)
class Case:
    """One hostile request and what its answer must be."""

    name: str
    wire: bytes                       # everything the client sends (request line, headers, body)
    pieces: int = 1                   # sent in this many pieces ...
    gap_s: float = 0.0                # ... this long apart
    dribble_from: int = 0             # the bytes before this offset go at once, the rest in `pieces`
    status: tuple[int, ...] = ()      # the statuses allowed (empty: any below 500)
    field: str | None = None          # a field the answer must name: "segments.0.text", "model"; "body" = all of it
    half_close: bool = False          # the client shuts its sending side after the last piece
    answer_optional: bool = False     # the client gave up first: a close without an answer is right too


def request(body: bytes = b"", *, method: bytes = b"POST", path: bytes = b"/generate",
            content_type: bytes | None = b"application/json", length: int | None = None,
            headers: tuple[bytes, ...] = (), key: bool = True) -> bytes:
    """An HTTP/1.1 request with `body`; Content-Length is the body's unless `length` says otherwise (-1: none)."""
    lines = [method + b" " + path + b" HTTP/1.1", b"Host: 127.0.0.1", b"Connection: close"]
    if key:
        lines.append(b"Authorization: Bearer " + API_KEY.encode())
    if content_type is not None:
        lines.append(b"Content-Type: " + content_type)
    declared = len(body) if length is None else length
    if declared >= 0:
        lines.append(b"Content-Length: " + str(declared).encode())
    lines.extend(headers)
    return b"\r\n".join(lines) + b"\r\n\r\n" + body


def generate(text: str = "a person walks forward", duration: object = 2.0, **fields: object) -> bytes:
    """A POST /generate of one segment (JSON written by Python: lone surrogates stay escaped, NaN stays NaN)."""
    return request(json.dumps({"segments": [{"text": text, "duration": duration}], **fields}).encode())


def _raw(body: str) -> bytes:
    """A POST /generate of a JSON text written by hand (escapes as written)."""
    return request(body.encode())


OK = generate(seed=1)
SEG = '{"segments":[{"text":"walk","duration":2}]'          # a valid request, left open for one more field
HEAD_ONLY = OK[:OK.index(b"\r\n\r\n") + 4]


SURROGATES = [
    Case("lone high surrogate in text", _raw(r'{"segments":[{"text":"\ud800 walk","duration":2}]}'),
         status=(422,), field="segments.0.text"),
    Case("lone low surrogate in text", _raw(r'{"segments":[{"text":"walk \udfff","duration":2}]}'),
         status=(422,), field="segments.0.text"),
    Case("reversed surrogate pair", _raw(r'{"segments":[{"text":"\udc00\ud800","duration":2}]}'),
         status=(422,), field="segments.0.text"),
    Case("surrogate in text and a bad duration", _raw(r'{"segments":[{"text":"\ud800","duration":0.1}]}'),
         status=(422,), field="segments.0.duration"),
    Case("surrogate in the 2nd segment", _raw(r'{"segments":[{"text":"walk","duration":2},{"text":"\ud800"}]}'),
         status=(422,), field="segments.1.text"),
    Case("surrogate in model", _raw(SEG + r',"model":"\udbff"}'), status=(422,), field="model"),
    Case("surrogate in format", _raw(SEG + r',"format":"\ud800"}'), status=(422,), field="format"),
    Case("surrogate as a key", _raw(SEG + r',"\ud800":1}'), status=(422,)),
    Case("surrogate in an unknown field", _raw(SEG + r',"extra":"\ud800"}'), status=(422,), field="extra"),
    Case("surrogate in a stream flag", _raw(SEG + r',"stream":"\ud800"}'), status=(422,), field="stream"),
    Case("surrogate pair (an emoji) is text", _raw(r'{"segments":[{"text":"\ud83d\ude00 walk","duration":2}]}'),
         status=(200,)),
]

CHARACTERS = [
    Case("NUL in text", generate("\x00 walk"), status=(200,)),
    Case("only NULs", generate("\x00\x00"), status=(200, 422)),
    Case("raw NUL byte inside a JSON string", _raw('{"segments":[{"text":"wa\x00lk","duration":2}]}'),
         status=(422,), field="body"),
    Case("control characters and ANSI escapes", generate("\x07\x1b[31m walk \x1b[0m\x7f"), status=(200,)),
    Case("line and paragraph separators", generate("walk\u2028run\u2029"), status=(200,)),
    Case("right-to-left override", generate("\u202ekaw nosrep a"), status=(200,)),
    Case("300 emoji", generate("\U0001f600" * 300), status=(200,)),
    Case("301 emoji", generate("\U0001f600" * 301), status=(422,), field="segments.0.text"),
    Case("combining marks", generate("w" + "\u0301" * 299), status=(200,)),
    Case("noncharacters", generate("\ufffe\uffff\U0010ffff walk"), status=(200,)),
    Case("only white space (unicode)", generate("\u3000\u00a0\u2003"), status=(422,), field="segments.0.text"),
    Case("NUL in a header value", request(json.dumps({"segments": [{"text": "walk"}]}).encode(),
                                          headers=(b"X-Note: a\x00b",))),
]

NUMBERS = [
    Case("NaN duration", _raw('{"segments":[{"text":"walk","duration":NaN}]}'), status=(422,),
         field="segments.0.duration"),
    Case("Infinity guidance", _raw(SEG + ',"guidance":Infinity}'), status=(422,), field="guidance"),
    Case("-Infinity temperature", _raw(SEG + ',"temperature":-Infinity}'), status=(422,), field="temperature"),
    Case("NaN seed", _raw(SEG + ',"seed":NaN}'), status=(422,), field="seed"),
    Case("1e999 duration (infinite)", _raw('{"segments":[{"text":"walk","duration":1e999}]}'), status=(422,),
         field="segments.0.duration"),
    Case("1e308 duration", _raw('{"segments":[{"text":"walk","duration":1e308}]}'), status=(422,),
         field="segments.0.duration"),
    Case("subnormal duration", _raw('{"segments":[{"text":"walk","duration":5e-324}]}'), status=(422,),
         field="segments.0.duration"),
    Case("seed 2**64", _raw(SEG + f',"seed":{2**64}}}'), status=(422,), field="seed"),
    Case("seed 2**64 as a float", _raw(SEG + ',"seed":1.8446744073709552e19}'), status=(422,), field="seed"),
    Case("seed -2**63", _raw(SEG + f',"seed":{-2**63}}}'), status=(422,), field="seed"),
    Case("seed 2**53 - 1 (the largest)", _raw(SEG + f',"seed":{2**53 - 1}}}'), status=(200,)),
    Case("seed of 4000 digits", _raw(SEG + ',"seed":' + "9" * 4000 + "}"), status=(422,), field="seed"),
    Case("seed of 5000 digits (past the parser's limit)", _raw(SEG + ',"seed":' + "9" * 5000 + "}"),
         status=(400,)),
    Case("top_k 1e400", _raw(SEG + ',"top_k":1e400}'), status=(422,), field="top_k"),
    Case("top_k 2**64", _raw(SEG + f',"top_k":{2**64}}}'), status=(422,), field="top_k"),
    Case("smallest temperature", _raw(SEG + ',"temperature":5e-324}')),
    Case("largest temperature", _raw(SEG + ',"temperature":5}'), status=(200,)),
    Case("negative zero duration", _raw('{"segments":[{"text":"walk","duration":-0.0}]}'), status=(422,),
         field="segments.0.duration"),
    Case("guidance 1e-320", _raw(SEG + ',"guidance":1e-320}'), status=(200,)),
    Case("exponent overflow in a number", _raw('{"segments":[{"text":"walk","duration":1e99999999999}]}'),
         status=(422,), field="segments.0.duration"),
]


def _nested(depth: int, where: str) -> bytes:
    inner = "[" * depth + "]" * depth
    if where == "text":
        return _raw('{"segments":[{"text":' + inner + ',"duration":2}]}')
    if where == "extra":
        return _raw(SEG + ',"x":' + '{"a":' * depth + "1" + "}" * depth + "}")
    return _raw('{"segments":' + inner + "}")


STRUCTURE = [
    *(Case(f"nested {depth} deep in {where}", _nested(depth, where), status=(400, 422))
      for depth in (100, 500, 900, 2000, 10000) for where in ("text", "extra", "segments")),
    Case("duplicate keys: the last empty", _raw('{"segments":[{"text":"walk","duration":2}],"segments":[]}'),
         status=(422,), field="segments"),
    Case("duplicate keys: the last valid", _raw('{"segments":[],"segments":[{"text":"walk","duration":2}]}'),
         status=(200,)),
    Case("duplicate seed keys", _raw(SEG + ',"seed":1,"seed":-1}'), status=(422,), field="seed"),
    Case("33 segments", request(json.dumps({"segments": [{"text": "a"}] * 33}).encode()), status=(422,),
         field="segments"),
    Case("JSON array as the body", _raw("[]"), status=(422,), field="body"),
    Case("JSON string as the body", _raw('"\\ud800"'), status=(422,), field="body"),
    Case("JSON null as the body", _raw("null"), status=(422,)),
    Case("JSON number as the body", _raw("1e999"), status=(422,), field="body"),
    Case("empty body", request(b""), status=(422,)),
    Case("segments is an object", _raw('{"segments":{"text":"walk"}}'), status=(422,), field="segments"),
    Case("text is an object", _raw('{"segments":[{"text":{"$gt":""},"duration":2}]}'), status=(422,),
         field="segments.0.text"),
    Case("prototype pollution keys", _raw(SEG + ',"__proto__":{"x":1},"constructor":{}}'), status=(422,),
         field="__proto__"),
]

ENCODINGS = [
    Case("Latin-1 body", generate().replace(b"forward", "f\xf6rward".encode("latin-1")), status=(400,)),
    Case("UTF-16 body with BOM", request(json.dumps({"segments": [{"text": "walk"}]}).encode("utf-16"))),
    Case("UTF-16-LE body without BOM", request(json.dumps({"segments": [{"text": "walk"}]}).encode("utf-16-le"))),
    Case("UTF-32 body", request(json.dumps({"segments": [{"text": "walk"}]}).encode("utf-32"))),
    Case("UTF-8 BOM", request(b"\xef\xbb\xbf" + json.dumps({"segments": [{"text": "walk"}]}).encode())),
    Case("invalid UTF-8 in a string", request(b'{"segments":[{"text":"walk \xff\xfe"}]}'), status=(400,)),
    Case("overlong UTF-8 slash", request(b'{"segments":[{"text":"\xc0\xaf walk"}]}'), status=(400,)),
    # json.loads reads UTF-8 bytes with "surrogatepass": these bytes become a lone surrogate in the text
    Case("CESU-8 surrogate bytes", request(b'{"segments":[{"text":"\xed\xa0\x80 walk"}]}'), status=(422,),
         field="segments.0.text"),
    Case("truncated UTF-8 sequence at the end", request(b'{"segments":[{"text":"walk \xe2\x82'), status=(400,)),
    Case("charset=latin-1 declared on a UTF-8 body",
         request(json.dumps({"segments": [{"text": "walk"}]}).encode(), content_type=b"application/json; "
                                                                                     b"charset=latin-1")),
]

CONTENT_TYPES = [
    Case("text/plain JSON", request(OK.split(b"\r\n\r\n", 1)[1], content_type=b"text/plain"), status=(422,),
         field="body"),
    Case("text/plain invalid UTF-8", request(b"\xff\xfe\x00{", content_type=b"text/plain"), status=(422,),
         field="body"),
    Case("no content type, invalid UTF-8", request(b"\xff\xfe\x00{", content_type=None), status=(422,),
         field="body"),
    Case("form-urlencoded", request(b"segments=walk&x=\xff", content_type=b"application/x-www-form-urlencoded"),
         status=(422,), field="body"),
    Case("multipart without a boundary", request(b"--x\r\n\r\n--x--", content_type=b"multipart/form-data"),
         status=(422,), field="body"),
    Case("octet-stream of zero bytes", request(b"\x00" * 100, content_type=b"application/octet-stream"),
         status=(422,), field="body"),
    Case("application/problem+json", request(OK.split(b"\r\n\r\n", 1)[1],
                                             content_type=b"application/problem+json"), status=(200,)),
    Case("content type of raw high bytes", request(b"{}", content_type=b"application/\xff\xfe+json")),
    Case("content type of 4 KB", request(b"{}", content_type=b"application/json; x=" + b"a" * 4096)),
    Case("XML body", request(b"<?xml version='1.0'?><!DOCTYPE x [<!ENTITY a 'b'>]><x>&a;</x>",
                             content_type=b"application/xml"), status=(422,), field="body"),
]

SIZES = [
    Case("body just over the limit", request(b" " * (MAX_BODY_BYTES + 1)), status=(413,)),
    Case("declared 1 GB, sends 1 KB", request(b" " * 1024, length=10**9), status=(413,)),
    Case("declared 10**30 bytes", request(b"{}", length=10**30), status=(400, 413)),
    Case("negative Content-Length", request(b"{}", length=-1, headers=(b"Content-Length: -5",)), status=(400,)),
    Case("non-numeric Content-Length", request(b"{}", length=-1, headers=(b"Content-Length: 2x",)), status=(400,)),
    Case("two different Content-Lengths", request(b"{}", headers=(b"Content-Length: 1",)), status=(400,)),
    Case("chunked body over the limit", request(
        (b"4000\r\n" + b" " * 0x4000 + b"\r\n") * 5 + b"0\r\n\r\n", length=-1,
        headers=(b"Transfer-Encoding: chunked",)), status=(413,)),
    Case("malformed chunk size", request(b"zz\r\nab\r\n0\r\n\r\n", length=-1,
                                         headers=(b"Transfer-Encoding: chunked",)), status=(400,)),
    Case("chunked and Content-Length both", request(b"2\r\n{}\r\n0\r\n\r\n", headers=(b"Transfer-Encoding: chunked",)),
         status=(400, 422)),
    Case("truncated JSON, honest length", request(OK.split(b"\r\n\r\n", 1)[1][:25]), status=(422,), field="body"),
    Case("Content-Length shorter than the body", request(b'{"segments":[]}xxxxxxxx', length=15), status=(422,),
         field="segments"),
    Case("header line of 100 KB", request(b"{}", headers=(b"X-Big: " + b"a" * 100_000,)),
         status=(400, 413, 422, 431)),
    Case("10,000 headers", request(b"{}", headers=tuple(b"X-%d: 1" % i for i in range(10_000))),
         status=(400, 413, 422, 431)),
    Case("URL of 60 KB", request(b"", method=b"GET", path=b"/health?" + b"a" * 60_000), status=(200, 400, 414)),
]

PATHS = [
    Case("model ../../etc/passwd", generate(model="../../etc/passwd"), status=(422,), field="model"),
    Case("model /etc/passwd", generate(model="/etc/passwd"), status=(422,), field="model"),
    Case("model ..\\..\\windows\\win.ini", generate(model="..\\..\\windows\\win.ini"), status=(422,), field="model"),
    Case("model: a bundle folder name", generate(model="default"), status=(422,), field="model"),
    Case("model: the embedded gpt folder relative", generate(model="../gpt"), status=(422,), field="model"),
    Case("model with a NUL", generate(model="default\x00.json"), status=(422,), field="model"),
    Case("model file:// URL", generate(model="file:///etc/passwd"), status=(422,), field="model"),
    Case("model of 201 characters", generate(model="a" * 201), status=(422,), field="model"),
    Case("static ../", request(method=b"GET", path=b"/static/../../../../etc/passwd", content_type=None),
         status=(400, 404)),
    Case("static %2e%2e", request(method=b"GET", path=b"/static/%2e%2e/%2e%2e/app.py", content_type=None),
         status=(400, 404)),
    Case("static %00", request(method=b"GET", path=b"/static/index.html%00.png", content_type=None),
         status=(400, 404)),
    Case("static backslashes", request(method=b"GET", path=b"/static/..\\..\\app.py", content_type=None),
         status=(400, 404)),
    Case("path of raw high bytes", request(method=b"GET", path=b"/\xff\xfe", content_type=None), status=(400, 404)),
    Case("percent-encoded surrogate in the path", request(method=b"GET", path=b"/%ED%A0%80", content_type=None),
         status=(400, 404)),
    Case("GET /generate", request(method=b"GET", content_type=None), status=(405,)),
    Case("DELETE /health", request(method=b"DELETE", path=b"/health", content_type=None), status=(405,)),
    Case("unknown method", request(method=b"BREW", path=b"/health", content_type=None), status=(400, 405, 501)),
]

AUTH = [
    Case("no API key", request(OK.split(b"\r\n\r\n", 1)[1], key=False), status=(401,)),
    Case("API key of high bytes", request(b"{}", key=False, headers=(b"Authorization: Bearer \xff\xfe\x80",)),
         status=(401,)),
    Case("API key of 8 KB", request(b"{}", key=False, headers=(b"Authorization: Bearer " + b"k" * 8192,)),
         status=(401,)),
    Case("Authorization with a surrogate escape", request(b"{}", key=False, headers=(b"Authorization: \\ud800",)),
         status=(401,)),
]

PROTOCOL = [
    Case("TLS client hello", b"\x16\x03\x01\x00\xa5\x01\x00\x00\xa1\x03\x03" + b"\x00" * 64, status=(400,)),
    Case("HTTP/2 preface", b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n", status=(400,), answer_optional=True),
    Case("garbage request line", b"\x00\x01\x02 / HTTP/1.1\r\n\r\n", status=(400,)),
    Case("header without a colon", b"GET /health HTTP/1.1\r\nHost 127.0.0.1\r\n\r\n", status=(400,)),
    Case("bare LF line ends", b"GET /health HTTP/1.1\nHost: 127.0.0.1\nConnection: close\n\n", status=(200, 400)),
    Case("HTTP/1.0 without Host", b"GET /health HTTP/1.0\r\n\r\n", status=(200,)),
    Case("HTTP/9.9", b"GET /health HTTP/9.9\r\nHost: x\r\n\r\n", status=(400, 505)),
    Case("Expect: 100-continue", request(OK.split(b"\r\n\r\n", 1)[1], headers=(b"Expect: 100-continue",)),
         status=(200,)),
    Case("websocket upgrade to /generate", request(method=b"GET", content_type=None, headers=(
        b"Upgrade: websocket", b"Connection: Upgrade", b"Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==",
        b"Sec-WebSocket-Version: 13")), status=(405,)),   # no WebSocket routes: `t2m serve` runs uvicorn with ws="none"
    Case("pipelined: a request and garbage", b"GET /health HTTP/1.1\r\nHost: x\r\n\r\n\x00\xff garbage\r\n\r\n",
         status=(200, 400)),
]

TIMING = [
    Case("slow request: dribbled inside the deadline", OK, pieces=8, gap_s=HEADER_TIMEOUT_S / 16, status=(200,)),
    Case("slowloris: headers dribbled past the deadline", HEAD_ONLY[:-4], pieces=60, gap_s=0.1, status=(408,)),
    Case("connection with nothing sent", b"", status=(408,)),
    Case("half-sent request line", OK[:10], status=(408,)),
    Case("half-sent headers", OK[:60], status=(408,)),
    Case("headers without their blank line", HEAD_ONLY[:-2], status=(408,)),
    Case("headers, then no body (Content-Length larger than sent)", HEAD_ONLY, status=(408,)),
    Case("half-sent body", OK[:-20], status=(408,)),
    Case("body dribbled past the deadline", OK, dribble_from=len(HEAD_ONLY), pieces=40, gap_s=0.1, status=(408,)),
    Case("half-sent body, then the client half-closes", OK[:-20], half_close=True, answer_optional=True),
    Case("half-sent headers, then the client half-closes", OK[:60], half_close=True, answer_optional=True),
]

CASES: list[Case] = [*SURROGATES, *CHARACTERS, *NUMBERS, *STRUCTURE, *ENCODINGS, *CONTENT_TYPES, *SIZES, *PATHS,
                     *AUTH, *PROTOCOL, *TIMING]
