// A message decoded by Foxglove's parsers as plain JSON-like data: typed arrays as arrays,
// bigints as numbers (what `ttball dump` prints), for comparing field by field.
export function plain(value) {
  if (typeof value === "bigint") return Number(value);
  if (ArrayBuffer.isView(value)) return Array.from(value, plain);
  if (Array.isArray(value)) return value.map(plain);
  if (value && typeof value === "object") {
    return Object.fromEntries(Object.entries(value).map(([k, v]) => [k, plain(v)]));
  }
  return value;
}
