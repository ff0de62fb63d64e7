// Decoding the data `soma view` embeds (format "soma-view" 1; README "File
// formats", framework/view/view_data.h) and per-frame counts.

const TYPED = {
  uint8: Uint8Array,
  uint16: Uint16Array,
  int16: Int16Array,
  int32: Int32Array,
  uint32: Uint32Array,
  float32: Float32Array,
};

// PointStatus of framework/view/view_data.h.
export const STATUS = { NO_TRUTH: 0, CORRECT: 1, WRONG: 2, GHOST: 3, MISSED: 4 };

export const UNKNOWN_CONFIDENCE = 65535;

function decodeArray(name, entry) {
  const Type = TYPED[entry.dtype];
  if (!Type) throw new Error(`array ${name}: unknown dtype ${entry.dtype}`);
  const binary = atob(entry.base64);
  const bytes = new Uint8Array(binary.length);
  for (let i = 0; i < binary.length; i++) bytes[i] = binary.charCodeAt(i);
  const values = new Type(bytes.buffer, 0, bytes.length / Type.BYTES_PER_ELEMENT);
  if (values.length !== entry.length) {
    throw new Error(`array ${name}: ${values.length} values, expected ${entry.length}`);
  }
  return values;
}

// The page's data object from the JSON text of the data element.
export function decodeViewData(text) {
  if (!text || text.trim()[0] !== '{') {
    throw new Error('this is the soma view template without data: run `soma view <capture.c3d>`');
  }
  const meta = JSON.parse(text);
  if (meta.format !== 'soma-view' || meta.format_version !== 1) {
    throw new Error(`unsupported data: format ${meta.format} ${meta.format_version}`);
  }
  const arrays = {};
  for (const [name, entry] of Object.entries(meta.arrays)) {
    arrays[name] = decodeArray(name, entry);
  }
  delete meta.arrays;
  const data = { ...meta, ...arrays };
  const F = data.num_frames;
  if (data.frame.length !== F || data.offset.length !== F + 1 ||
      data.offset[F] !== data.num_points || data.position.length !== 3 * data.num_points) {
    throw new Error('inconsistent data: frame, offset and position lengths disagree');
  }
  data.nullId = data.labels.length;
  let maxPoints = 0;
  for (let f = 0; f < F; f++) {
    maxPoints = Math.max(maxPoints, data.offset[f + 1] - data.offset[f]);
  }
  data.maxPoints = maxPoints;
  return data;
}

// Counts of shown frame `f`: points and, with ground truth, per status.
export function frameCounts(data, f) {
  const begin = data.offset[f], end = data.offset[f + 1];
  const counts = { points: end - begin, labelled: 0, correct: 0, labelledCorrect: 0, wrong: 0, ghost: 0, missed: 0, noTruth: 0 };
  for (let i = begin; i < end; i++) {
    if (data.label[i] !== data.nullId) counts.labelled++;
    if (!data.has_truth) continue;
    switch (data.status[i]) {
      case STATUS.CORRECT:
        counts.correct++;
        if (data.label[i] !== data.nullId) counts.labelledCorrect++;
        break;
      case STATUS.WRONG: counts.wrong++; break;
      case STATUS.GHOST: counts.ghost++; break;
      case STATUS.MISSED: counts.missed++; break;
      default: counts.noTruth++;
    }
  }
  return counts;
}

// The shown frame nearest to take frame `t` (0-based).
export function shownFrameOf(data, t) {
  let lo = 0, hi = data.num_frames - 1;
  while (lo < hi) {
    const mid = (lo + hi + 1) >> 1;
    if (data.frame[mid] <= t) lo = mid; else hi = mid - 1;
  }
  if (lo + 1 < data.num_frames && Math.abs(data.frame[lo + 1] - t) < Math.abs(data.frame[lo] - t)) {
    return lo + 1;
  }
  return lo;
}
