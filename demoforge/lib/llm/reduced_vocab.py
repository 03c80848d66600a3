"""Greedy structured decoding with a reduced-vocabulary copy of the embedded GGUF.

Gemma 3's output head is tied to its 262,144 x 640 token embedding: every decode step computes all
262,144 logits although :func:`demoforge.lib.llm.structured_decoding.greedy_structured` reads only the
~150 action tokens'. The copy keeps every tensor as it is except ``token_embd.weight``, whose rows are
cut down to a subset of the vocabulary (:func:`reduced_ids`); the tokenizer arrays and special token ids
are remapped to match. The rows are selected by byte slicing (a quantized row is a whole number of
blocks), so a kept token's embedding and logit are the full model's.

* :func:`reduced_ids`: the action tokens, the tokens of every other piece made of digits, punctuation
  and whitespace, the control tokens (not the ``<unusedN>`` ones) and the 256 byte tokens llama.cpp's
  SPM vocabulary expects, and the tokens of the prompt template (sample prompts of every number format
  and encoding, tokenized by the full model). Padded with ``<unusedN>`` tokens to a multiple of 64 rows.
* :func:`reduced_gguf`: the copy, written once next to the original as
  ``<stem>.vocab-<hash of the id list>.gguf`` (temporary file, then rename) with a ``.sha256`` beside it;
  a file whose checksum does not match is rebuilt.
* :func:`decode`: the prompt's full ids mapped to reduced ids, answered by the reduced model (its own
  tokenizer is never used), the answer's ids mapped back. A prompt with a token outside the reduced
  vocabulary is answered by the full model (same answer, slower).
"""

from __future__ import annotations

import ctypes
import hashlib
import logging
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from demoforge.lib.llm.llama_models import MODEL_LOCK, load_model
from demoforge.lib.llm.number_format import NUMBER_FORMATS
from demoforge.lib.llm.prompting import build_prompt
from demoforge.lib.llm.structured_decoding import ALPHABET, DecodeResult, greedy_structured, token_piece

__all__ = ["WIDE_ALPHABET", "ReducedModel", "decode", "reduced_gguf", "reduced_ids", "reduced_model"]

log = logging.getLogger(__name__)

# pieces made of these alone are kept whatever the template: numbers, brackets, shapes, labels' punctuation
WIDE_ALPHABET = frozenset("0123456789-.,[]()#:*\n ") | ALPHABET
_ROW_MULTIPLE = 64  # whole blocks of rows for every matmul kernel (repacked layouts take 4 or 8 rows)
_IDS: dict[int, tuple[np.ndarray, Any]] = {}  # id(full model) -> ids, the model
_VERIFIED: set[str] = set()


def _sample_prompt_texts() -> list[str]:
    """Prompts of every number format and encoding with made-up numbers: their tokens include the
    template's words as the tokenizer merges them in context."""
    rng = np.random.default_rng(0)
    n = 40
    acts = np.zeros((n, 2, 8))
    acts[:, :, :3] = np.cumsum(rng.normal(0, 0.01, (n, 2, 3)), axis=0) + [0.4, -0.2, 0.9]
    acts[:, :, 3:7] = rng.normal(0, 1, (n, 2, 4))
    acts[:, :, 7] = 1.0
    acts[n // 3: 2 * n // 3, :, 7] = 0.0
    kp = rng.normal(0, 0.2, (11, 3))
    init = acts[0].copy()
    texts = []
    for fmt in NUMBER_FORMATS:
        for n_waypoints in (20, None):
            p = build_prompt([(kp, init, acts), (kp - 0.01, init, acts[::-1])], kp + 0.01, init,
                             n_waypoints=n_waypoints, number_format=fmt)
            texts.append(p.text)
    return texts


def _to_reduced(ids: np.ndarray, n_full: int) -> np.ndarray:
    """(n_full,) full id -> reduced id (its position in the sorted ``ids``), -1 where not kept."""
    out = np.full(int(n_full), -1, dtype=np.int64)
    out[ids] = np.arange(len(ids))
    return out


def reduced_ids(llm) -> np.ndarray:
    """The sorted full-vocabulary ids the reduced model keeps (module docstring). Once per model."""
    with MODEL_LOCK:
        hit = _IDS.get(id(llm))
        if hit is not None and hit[1] is llm:
            return hit[0]
        import llama_cpp

        vocab = llm._model.vocab
        buf = ctypes.create_string_buffer(256)
        keep: set[int] = set()
        unused: list[int] = []
        for tok in range(llm.n_vocab()):
            attr = llama_cpp.llama_vocab_get_attr(vocab, tok)
            if attr & llama_cpp.LLAMA_TOKEN_ATTR_BYTE:
                keep.add(tok)
                continue
            if attr & llama_cpp.LLAMA_TOKEN_ATTR_CONTROL:
                text = (llama_cpp.llama_vocab_get_text(vocab, tok) or b"").decode("utf-8", "replace")
                if text.startswith("<unused"):
                    unused.append(tok)
                else:
                    keep.add(tok)
                continue
            piece = token_piece(vocab, tok, buf)
            if piece and set(piece) <= WIDE_ALPHABET:
                keep.add(tok)
        for text in _sample_prompt_texts():
            keep.update(llm.tokenize(text.encode("utf-8"), add_bos=True, special=True))
        for s in (llm.token_bos(), llm.token_eos()):
            if s >= 0:
                keep.add(int(s))
        pad = [t for t in unused if t not in keep][: (-len(keep)) % _ROW_MULTIPLE]
        ids = np.asarray(sorted(keep | set(pad)), dtype=np.int64)
        _IDS[id(llm)] = (ids, llm)
        return ids


def _digest(ids: np.ndarray) -> str:
    return hashlib.sha256(np.asarray(ids, dtype="<i8").tobytes()).hexdigest()[:16]


def _file_sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 22), b""):
            h.update(chunk)
    return h.hexdigest()


def _valid(target: Path) -> bool:
    side = target.with_name(target.name + ".sha256")
    try:
        want = side.read_text().split()[0]
    except (OSError, IndexError):
        return False
    return target.exists() and _file_sha256(target) == want


def reduced_gguf(src: str | os.PathLike, ids: np.ndarray) -> Path:
    """The reduced copy of ``src`` keeping ``ids`` (sorted full ids), built once next to ``src``; a copy
    whose checksum does not match its ``.sha256`` (truncated, overwritten) is rebuilt."""
    src = Path(src)
    ids = np.asarray(ids, dtype=np.int64)
    target = src.with_name(f"{src.stem}.vocab-{_digest(ids)}.gguf")
    with MODEL_LOCK:
        if str(target) in _VERIFIED and target.exists():
            return target
        if not _valid(target):
            if target.exists():
                log.warning("reduced-vocabulary GGUF %s does not match its checksum: rebuilding it", target)
            _build(src, ids, target)
            if not _valid(target):
                raise OSError(f"reduced-vocabulary GGUF {target} failed its checksum right after it was written")
        _VERIFIED.add(str(target))
        return target


def _build(src: Path, ids: np.ndarray, target: Path) -> None:
    import gguf

    reader = gguf.GGUFReader(src)
    n_full = len(reader.fields["tokenizer.ggml.tokens"].data)
    remap = _to_reduced(ids, n_full)
    arch = reader.fields["general.architecture"].contents()
    fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=".gguf", dir=target.parent)
    os.close(fd)
    try:
        writer = gguf.GGUFWriter(tmp, arch=arch, endianess=reader.endianess)
        align = reader.fields.get("general.alignment")
        if align is not None:
            writer.data_alignment = int(align.contents())
        for field in reader.fields.values():
            if field.name == "general.architecture" or field.name.startswith("GGUF."):
                continue
            vtype = field.types[0]
            sub = field.types[-1] if vtype == gguf.GGUFValueType.ARRAY else None
            if vtype == gguf.GGUFValueType.ARRAY and len(field.data) == n_full:
                if sub == gguf.GGUFValueType.STRING:  # raw bytes: no decode/encode round trip
                    value = [bytes(field.parts[field.data[i]]) for i in ids]
                else:
                    value = [field.parts[field.data[i]].tolist()[0] for i in ids]
            elif field.name.startswith("tokenizer.ggml.") and field.name.endswith("_token_id"):
                old = int(field.contents())
                new = int(remap[old]) if 0 <= old < n_full else -1
                if new < 0:
                    raise ValueError(f"{field.name} = {old} is not among the reduced vocabulary's ids")
                value = new
            else:
                value = field.contents()
            writer.add_key_value(field.name, value, vtype, sub_type=sub)
        writer.add_key_value("demoforge.reduced_vocab.source", src.name, gguf.GGUFValueType.STRING)
        writer.add_key_value("demoforge.reduced_vocab.ids", [int(i) for i in ids], gguf.GGUFValueType.ARRAY,
                             sub_type=gguf.GGUFValueType.UINT32)
        data = {}
        for t in reader.tensors:
            d = t.data
            if t.name in ("token_embd.weight", "output.weight"):
                if d.shape[0] != n_full:
                    raise ValueError(f"{t.name}: {d.shape[0]} rows, the vocabulary has {n_full}")
                d = np.ascontiguousarray(d[ids])  # whole rows: whole quantization blocks
            data[t.name] = d
            writer.add_tensor_info(t.name, d.shape, d.dtype, d.nbytes, t.tensor_type)
        writer.write_header_to_file()
        writer.write_kv_data_to_file()
        writer.write_ti_data_to_file()
        for t in reader.tensors:
            writer.write_tensor_data(data[t.name], tensor_endianess=reader.endianess)
        writer.close()
        os.chmod(tmp, 0o644)  # mkstemp's 0600 would hide the shared model from other users of the venv
        digest = _file_sha256(Path(tmp))
        os.replace(tmp, target)
        side = target.with_name(target.name + ".sha256")
        fd, tmp_side = tempfile.mkstemp(prefix=".tmp-", suffix=".sha256", dir=target.parent)
        with os.fdopen(fd, "w") as f:
            f.write(f"{digest}  {target.name}\n")
        os.replace(tmp_side, side)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


@dataclass
class ReducedModel:
    llm: Any  # llama_cpp.Llama of the reduced GGUF
    ids: np.ndarray  # reduced id -> full id
    to_reduced: np.ndarray  # full id -> reduced id, -1 when not kept
    path: Path

    def map_prompt(self, tokens: list[int]) -> list[int] | None:
        """``tokens`` (full ids) as reduced ids, None when one of them is not kept."""
        r = self.to_reduced[np.asarray(tokens, dtype=np.int64)]
        return None if (r < 0).any() else r.tolist()


_REDUCED: dict[tuple, ReducedModel] = {}


def reduced_model(full_llm, src: str | os.PathLike, n_ctx: int, n_threads: int | None, n_batch: int,
                  swa_full: bool) -> ReducedModel:
    """The reduced model of ``src`` (whose loaded full model is ``full_llm``), built and loaded once."""
    with MODEL_LOCK:  # the backend's: the models are loaded and called under it
        ids = reduced_ids(full_llm)
        path = reduced_gguf(src, ids)
        llm = load_model(path, n_ctx, n_threads, n_batch, swa_full)
        key = (str(path), id(llm))
        hit = _REDUCED.get(key)
        if hit is not None and hit.llm is llm:
            return hit
        if llm.n_vocab() != len(ids):
            raise ValueError(f"{path}: {llm.n_vocab()} tokens, expected {len(ids)}")
        m = ReducedModel(llm, ids, _to_reduced(ids, full_llm.n_vocab()), path)
        _REDUCED[key] = m
        return m


def decode(full_llm, reduced: ReducedModel | None, prompt_tokens: list[int], language, max_tokens: int,
           reuse_prefix: bool = False) -> tuple[DecodeResult, bool]:
    """``greedy_structured``'s answer, by the reduced model when every prompt token is kept in it, else by
    ``full_llm``. Returns the result (full ids, text by the full tokenizer) and whether the reduced model
    answered."""
    mapped = reduced.map_prompt(prompt_tokens) if reduced is not None else None
    if mapped is None:
        return greedy_structured(full_llm, prompt_tokens, language, max_tokens, reuse_prefix=reuse_prefix), False
    r = greedy_structured(reduced.llm, mapped, language, max_tokens, reuse_prefix=reuse_prefix)
    tokens = [int(reduced.ids[t]) for t in r.tokens]
    text = full_llm.detokenize(tokens).decode("utf-8", errors="replace")
    return DecodeResult(text=text, tokens=tokens, finish_reason=r.finish_reason,
                        prompt_tokens=len(prompt_tokens)), True
