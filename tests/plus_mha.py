#!/usr/bin/env python3
"""A PLUS sequence (.mha, data LOCAL, raw or zlib) read the way PLUS's
vtkPlusMetaImageSequenceIO reads one, written here from the format alone and
independent of pp5echo's reader: 'key = value' header lines up to
ElementDataFile, the frames' fields as Seq_FrameNNNN_<key>, then the data.

  plus_mha.py count FILE          prints the number of frames
  plus_mha.py prefix A B          A's frames are B's first frames: the same
                                  pixels and every Transform field of A's frames
                                  the same text in B (exit 1 otherwise)
"""
import re
import sys
import zlib


def read(path):
    with open(path, 'rb') as f:
        data = f.read()
    fields, frames, at = {}, {}, 0
    while True:
        end = data.index(b'\n', at)
        line = data[at:end].decode('latin-1').rstrip('\r')
        at = end + 1
        key, _, value = line.partition('=')
        key, value = key.strip(), value.strip()
        m = re.match(r'Seq_Frame(\d+)_(.+)$', key)
        if m:
            frames.setdefault(int(m.group(1)), {})[m.group(2)] = value
        else:
            fields[key] = value
        if key == 'ElementDataFile':
            break
    if fields['ElementDataFile'] != 'LOCAL':
        raise SystemExit(f'{path}: data not LOCAL')
    dims = [int(v) for v in fields['DimSize'].split()]
    bpp = {'MET_UCHAR': 1, 'MET_USHORT': 2}[fields['ElementType']]
    blob = data[at:]
    if fields.get('CompressedData', 'False').lower() == 'true':
        blob = zlib.decompress(blob[:int(fields['CompressedDataSize'])])
    n = dims[2] if len(dims) > 2 else 1
    size = dims[0] * dims[1] * bpp
    if len(blob) != size * n:
        raise SystemExit(f'{path}: {len(blob)} bytes of data, DimSize {dims} needs {size * n}')
    if any(i >= n for i in frames):
        raise SystemExit(f'{path}: fields for frame {max(frames)} of {n}')
    return n, [blob[i * size:(i + 1) * size] for i in range(n)], frames


def main():
    if sys.argv[1] == 'count':
        print(read(sys.argv[2])[0])
        return 0
    na, pa, fa = read(sys.argv[2])
    nb, pb, fb = read(sys.argv[3])
    if na > nb:
        print(f'{sys.argv[2]} has {na} frames, {sys.argv[3]} only {nb}')
        return 1
    for i in range(na):
        if pa[i] != pb[i]:
            print(f'frame {i}: the pixels differ')
            return 1
        for k, v in fa.get(i, {}).items():
            if k.endswith('Transform') and fb.get(i, {}).get(k) != v:
                print(f'frame {i}: {k} is {v!r} in one, {fb.get(i, {}).get(k)!r} in the other')
                return 1
    print(f'{na} frames, the first {na} of {nb}: same pixels and transforms')
    return 0


if __name__ == '__main__':
    sys.exit(main())
