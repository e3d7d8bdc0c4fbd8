#include "sketch/tilt.h"

#include <zip.h>

#include <array>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <memory>
#include <nlohmann/json.hpp>

#include "core/error.h"

namespace physketch::sketch {
namespace {

constexpr std::uint32_t kSketchSentinel = 0xc576a5cdu;
constexpr std::size_t kMaxMember = std::size_t(1) << 30;  // 1 GiB: a bound on what a member may claim
constexpr std::int64_t kMaxStrokes = 10'000'000;

[[noreturn]] void bad(const std::string& path, const std::string& field, const std::string& what) {
  throw InputError(path, 0, field, what);
}

// The whole file, its fixed header checked: "tilT", u16 header size, u16 version (1), two
// reserved u32. Returns the header size (where the zip begins).
std::size_t readFile(const std::string& path, std::string& bytes) {
  std::ifstream in(path, std::ios::binary);
  if (!in) bad(path, "", "cannot open the file");
  in.seekg(0, std::ios::end);
  const std::streamoff size = in.tellg();
  if (size < 0 || static_cast<std::uint64_t>(size) > kMaxMember) bad(path, "", "cannot read the file, or it is over 1 GiB");
  bytes.resize(static_cast<std::size_t>(size));
  in.seekg(0);
  in.read(bytes.data(), size);
  if (in.gcount() != size) bad(path, "", "cannot read the file");
  const auto byte = [&](std::size_t i) { return static_cast<unsigned>(static_cast<unsigned char>(bytes[i])); };
  if (bytes.size() < 8 || bytes.compare(0, 4, "tilT") != 0)
    bad(path, "header", "not a .tilt file: it does not start with the 'tilT' header of Tilt Brush / Open Brush");
  const std::size_t head = byte(4) | (byte(5) << 8);
  const unsigned version = byte(6) | (byte(7) << 8);
  if (version != 1) bad(path, "header", "header version " + std::to_string(version) + " (only 1 is known)");
  if (head < 8) bad(path, "header", "header size " + std::to_string(head) + " is smaller than the header");
  if (bytes.size() < head + 4 || bytes.compare(head, 4, "PK\x03\x04") != 0)
    bad(path, "header", "no zip archive after the " + std::to_string(head) + "-byte header (truncated or corrupt)");
  return head;
}

struct FileCloser {
  void operator()(zip_file_t* f) const { zip_fclose(f); }
};

std::string readMember(zip_t* zip, const char* name, const std::string& path) {
  zip_stat_t st;
  zip_stat_init(&st);
  if (zip_stat(zip, name, ZIP_FL_ENC_GUESS, &st) != 0)
    bad(path, name, std::string("the archive has no ") + name + " (not a sketch, or a corrupt file)");
  if (!(st.valid & ZIP_STAT_SIZE) || st.size > kMaxMember)
    bad(path, name, "member size unknown or over 1 GiB");
  std::unique_ptr<zip_file_t, FileCloser> f(zip_fopen(zip, name, 0));
  if (!f) bad(path, name, std::string("cannot open the member: ") + zip_strerror(zip));
  std::string bytes(static_cast<std::size_t>(st.size), '\0');
  std::size_t got = 0;
  while (got < bytes.size()) {
    const zip_int64_t n = zip_fread(f.get(), bytes.data() + got, bytes.size() - got);
    if (n < 0) bad(path, name, std::string("cannot read the member: ") + zip_file_strerror(f.get()));
    if (n == 0) break;
    got += static_cast<std::size_t>(n);
  }
  if (got != bytes.size())
    bad(path, name, "the member ends after " + std::to_string(got) + " of " + std::to_string(bytes.size()) + " bytes");
  // libzip checks the member's CRC-32 when a read reaches its end: read once more.
  char extra;
  if (zip_fread(f.get(), &extra, 1) != 0)
    bad(path, name, std::string("corrupt member (its CRC-32 or size does not match): ") + zip_file_strerror(f.get()));
  return bytes;
}

// Little-endian reads from data.sketch with bounds checks; `where` names what is read.
class Reader {
 public:
  Reader(const std::string& bytes, const std::string& path) : b_(bytes), path_(path) {}
  std::uint32_t u32(const std::string& where) {
    need(4, where);
    std::uint32_t v = 0;
    for (int i = 3; i >= 0; --i) v = (v << 8) | static_cast<unsigned char>(b_[pos_ + static_cast<std::size_t>(i)]);
    pos_ += 4;
    return v;
  }
  std::int32_t i32(const std::string& where) { return static_cast<std::int32_t>(u32(where)); }
  double f32(const std::string& where) {
    const std::uint32_t bits = u32(where);
    float f;
    std::memcpy(&f, &bits, sizeof f);
    if (!std::isfinite(f)) bad(path_, "data.sketch", where + " is not a finite number");
    return f;
  }
  void skip(std::size_t n, const std::string& where) {
    need(n, where);
    pos_ += n;
  }
  std::size_t left() const { return b_.size() - pos_; }

 private:
  void need(std::size_t n, const std::string& where) const {
    if (b_.size() - pos_ < n)
      bad(path_, "data.sketch", "truncated: the data ends in " + where + " (byte " + std::to_string(pos_) + " of " +
                                    std::to_string(b_.size()) + ")");
  }
  const std::string& b_;
  const std::string& path_;
  std::size_t pos_ = 0;
};

std::vector<std::string> brushIndex(const std::string& json, const std::string& path) {
  nlohmann::json meta;
  try {
    meta = nlohmann::json::parse(json);
  } catch (const nlohmann::json::exception& e) {
    bad(path, "metadata.json", std::string("not JSON: ") + e.what());
  }
  if (!meta.is_object() || !meta.contains("BrushIndex") || !meta["BrushIndex"].is_array())
    bad(path, "metadata.json", "has no BrushIndex array (the brush of every stroke)");
  std::vector<std::string> out;
  for (const auto& g : meta["BrushIndex"]) {
    if (!g.is_string()) bad(path, "metadata.json", "BrushIndex holds something that is not a GUID string");
    out.push_back(g.get<std::string>());
  }
  return out;
}

// Open Brush's "Layers": [{"Name", "Visible", "Transform": [[tx,ty,tz],[qx,qy,qz,qw],s]}, ...]
// (all optional; absent: no layers). A scale of 0 means 1, as Open Brush reads it.
std::vector<TiltLayer> layers(const std::string& json, const std::string& path) {
  const nlohmann::json meta = nlohmann::json::parse(json);  // brushIndex has parsed it
  std::vector<TiltLayer> out;
  if (!meta.contains("Layers")) return out;
  const auto& list = meta["Layers"];
  if (!list.is_array()) bad(path, "metadata.json", "Layers is not an array");
  for (std::size_t i = 0; i < list.size(); ++i) {
    const std::string at = "Layers[" + std::to_string(i) + "]";
    const auto& l = list[i];
    if (!l.is_object()) bad(path, "metadata.json", at + " is not an object");
    TiltLayer layer;
    if (l.contains("Name") && l["Name"].is_string()) layer.name = l["Name"].get<std::string>();
    if (l.contains("Visible")) {
      if (!l["Visible"].is_boolean()) bad(path, "metadata.json", at + ".Visible is not true or false");
      layer.visible = l["Visible"].get<bool>();
    }
    if (l.contains("Transform") && !l["Transform"].is_null()) {
      const auto& t = l["Transform"];
      const auto numbers = [&](const nlohmann::json& a, std::size_t n) {
        std::vector<double> v;
        if (a.is_array() && a.size() == n)
          for (const auto& x : a)
            if (x.is_number() && std::isfinite(x.get<double>())) v.push_back(x.get<double>());
        return v;
      };
      const std::vector<double> tr = t.is_array() && t.size() == 3 ? numbers(t[0], 3) : std::vector<double>{};
      const std::vector<double> q = t.is_array() && t.size() == 3 ? numbers(t[1], 4) : std::vector<double>{};
      const bool scaleOk = t.is_array() && t.size() == 3 && t[2].is_number() && std::isfinite(t[2].get<double>()) &&
                           t[2].get<double>() >= 0.0;
      const double qn = q.size() == 4 ? std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]) : 0.0;
      if (tr.size() != 3 || q.size() != 4 || !(qn > 1e-6) || !scaleOk)
        bad(path, "metadata.json",
            at + ".Transform is not [[tx, ty, tz], [qx, qy, qz, qw], scale] with finite numbers, a non-zero "
                 "quaternion and a scale >= 0");
      layer.translation = Vec3(tr[0], tr[1], tr[2]);
      layer.rotation = Quat(q[3] / qn, q[0] / qn, q[1] / qn, q[2] / qn);  // Eigen: (w, x, y, z)
      layer.scale = t[2].get<double>() > 0.0 ? t[2].get<double>() : 1.0;
    }
    out.push_back(layer);
  }
  return out;
}

}  // namespace

TiltSketch parseTilt(const std::string& dataSketch, const std::string& metadataJson, const std::string& path) {
  TiltSketch sk;
  sk.brushes = brushIndex(metadataJson, path);
  sk.layers = layers(metadataJson, path);
  Reader r(dataSketch, path);
  if (r.u32("the header") != kSketchSentinel)
    bad(path, "data.sketch", "bad sentinel: not Tilt Brush stroke data");
  r.u32("the header");
  r.u32("the header");
  r.skip(r.u32("the header"), "the additional header");
  const std::int32_t strokes = r.i32("the stroke count");
  // A stroke takes at least 36 bytes: a count larger than the data allows is corruption.
  if (strokes < 0 || strokes > kMaxStrokes || static_cast<std::size_t>(strokes) > r.left() / 36)
    bad(path, "data.sketch", "truncated or corrupt: a stroke count of " + std::to_string(strokes) + " is impossible in " +
                                 std::to_string(r.left()) + " bytes");
  sk.strokes.reserve(static_cast<std::size_t>(strokes));
  for (std::int32_t s = 0; s < strokes; ++s) {
    const std::string at = "stroke " + std::to_string(s + 1) + " of " + std::to_string(strokes);
    TiltStroke st;
    st.brushIndex = r.i32(at + ", brush index");
    if (st.brushIndex < 0 || static_cast<std::size_t>(st.brushIndex) >= sk.brushes.size())
      bad(path, "data.sketch", at + ": brush index " + std::to_string(st.brushIndex) + " is not in BrushIndex (" +
                                   std::to_string(sk.brushes.size()) + " brushes)");
    for (int c = 0; c < 3; ++c) st.color[c] = r.f32(at + ", colour");
    r.f32(at + ", colour");  // alpha
    if ((st.color.array() < 0.0).any()) bad(path, "data.sketch", at + ": negative colour");
    st.size = r.f32(at + ", brush size");
    if (st.size < 0) bad(path, "data.sketch", at + ": negative brush size");
    std::uint32_t strokeMask = r.u32(at + ", extension mask");
    const std::uint32_t pointMask = r.u32(at + ", point extension mask");
    for (; strokeMask; strokeMask &= strokeMask - 1) {
      const std::uint32_t bit = strokeMask & (~strokeMask + 1);
      const std::string ext = at + ", extension 0x" + [&] {
        char buf[16];
        std::snprintf(buf, sizeof buf, "%x", bit);
        return std::string(buf);
      }();
      if (bit == 0x2) {  // Open Brush lets a stroke's scale go negative (mirrored); its width is |scale|
        const double scale = r.f32(ext + " (scale)");
        st.negativeScale = scale < 0;
        st.size *= std::fabs(scale);
      } else if (bit == 0x10) {
        st.layer = r.u32(ext + " (layer)");
      } else if (bit & 0xffffu) {
        r.u32(ext);
      } else {
        r.skip(r.u32(ext + " length"), ext);
      }
    }
    st.hasPressure = pointMask & 0x1u;
    st.hasTimestamps = pointMask & 0x2u;
    const std::int32_t points = r.i32(at + ", point count");
    std::size_t perPoint = 28;
    for (std::uint32_t m = pointMask; m; m &= m - 1) perPoint += 4;
    if (points < 0 || static_cast<std::size_t>(points) > r.left() / perPoint)
      bad(path, "data.sketch", "truncated or corrupt: " + at + " has " + std::to_string(points) + " points of " +
                                   std::to_string(perPoint) + " bytes, but " + std::to_string(r.left()) +
                                   " bytes are left");
    st.points.resize(static_cast<std::size_t>(points));
    for (std::int32_t p = 0; p < points; ++p) {
      const std::string pat = at + ", point " + std::to_string(p + 1);
      TiltPoint& pt = st.points[static_cast<std::size_t>(p)];
      for (int c = 0; c < 3; ++c) pt.position[c] = r.f32(pat + ", position");
      for (int c = 0; c < 4; ++c) r.f32(pat + ", orientation");
      for (std::uint32_t m = pointMask; m; m &= m - 1) {
        const std::uint32_t bit = m & (~m + 1);
        if (bit == 0x1) {
          pt.pressure = r.f32(pat + ", pressure");
          if (pt.pressure < 0) bad(path, "data.sketch", pat + ": pressure " + std::to_string(pt.pressure) + " is negative");
        } else if (bit == 0x2) {
          pt.timestampMs = r.u32(pat + ", timestamp");
        } else {
          r.u32(pat + ", extension");
        }
      }
    }
    sk.strokes.push_back(std::move(st));
  }
  return sk;
}

namespace {

// Opens the zip in bytes [from, end). Null (and `why`) when libzip cannot.
std::unique_ptr<zip_t, void (*)(zip_t*)> openZip(const std::string& bytes, std::size_t from, std::string& why) {
  std::unique_ptr<zip_t, void (*)(zip_t*)> none(nullptr, [](zip_t*) {});
  zip_error_t err;
  zip_error_init(&err);
  zip_source_t* src = zip_source_buffer_create(bytes.data() + from, bytes.size() - from, 0, &err);
  zip_t* z = src ? zip_open_from_source(src, ZIP_RDONLY, &err) : nullptr;
  if (!z) {
    why = zip_error_strerror(&err);
    if (src) zip_source_free(src);
    zip_error_fini(&err);
    return none;
  }
  zip_error_fini(&err);
  return {z, [](zip_t* zz) { zip_discard(zz); }};
}

}  // namespace

TiltSketch readTilt(const std::string& path) {
  // Open Brush can also save a sketch as a folder named X.tilt holding the members as files
  // (its developer option, and the sketches it embeds).
  std::error_code ec;
  if (std::filesystem::is_directory(path, ec)) {
    const auto member = [&](const char* name) {
      const std::string file = (std::filesystem::path(path) / name).string();
      std::ifstream in(file, std::ios::binary);
      if (!in) bad(path, name, std::string("the folder has no readable ") + name + " (not a sketch saved as a folder)");
      std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
      if (bytes.size() > kMaxMember) bad(path, name, "member over 1 GiB");
      return bytes;
    };
    const std::string meta = member("metadata.json");
    return parseTilt(member("data.sketch"), meta, path);
  }
  std::string bytes;
  const std::size_t head = readFile(path, bytes);
  // Tilt Brush and Open Brush count the zip's offsets from the end of the header (the zip
  // alone is a valid archive); a writer that streamed the header into the archive counts
  // them from the start of the file. Try the first, then the second.
  std::string why;
  auto zip = openZip(bytes, head, why);
  if (!zip) {
    std::string why2;
    zip = openZip(bytes, 0, why2);
    if (!zip) bad(path, "", "not a readable zip archive after the header: " + why + " (truncated or corrupt)");
  }
  const std::string meta = readMember(zip.get(), "metadata.json", path);
  const std::string data = readMember(zip.get(), "data.sketch", path);
  return parseTilt(data, meta, path);
}

std::string tiltBrushName(const std::string& guid) {
  // GUIDs of the brushes of Tilt Brush 1.x (tilt-brush-toolkit's UnitySDK brush assets);
  // Open Brush keeps them. Versions of one brush share its name.
  static const std::pair<const char*, const char*> kBrushes[] = {
      {"89d104cd-d012-426b-b5b3-bbaee63ac43c", "Bubbles"},     {"700f3aa8-9a7c-2384-8b8a-ea028905dd8c", "CelVinyl"},
      {"0f0ff7b2-a677-45eb-a7d6-0cd7206f4816", "ChromaticWave"}, {"1161af82-50cf-47db-9706-0c3576d43c43", "CoarseBristles"},
      {"79168f10-6961-464a-8be1-57ed364c5600", "CoarseBristles"}, {"1caa6d7d-f015-3f54-3a4b-8b5354d39f81", "Comet"},
      {"c8313697-2563-47fc-832e-290f4c04b901", "DiamondHull"}, {"4391aaaa-df73-4396-9e33-31e4e4930b27", "Disco"},
      {"d1d991f2-e7a0-4cf1-b328-f57e915e6260", "DotMarker"},   {"6a1cf9f9-032c-45ec-9b1d-a6680bee30f7", "Dots"},
      {"0d3889f3-3ede-470c-8af4-f44813306126", "DoubleTaperedFlat"},
      {"0d3889f3-3ede-470c-8af4-de4813306126", "DoubleTaperedMarker"},
      {"d0262945-853c-4481-9cbd-88586bed93cb", "DuctTape"},    {"3ca16e2f-bdcd-4da2-8631-dcef342f40f1", "DuctTape"},
      {"f6e85de3-6dcc-4e7f-87fd-cee8c3d25d51", "Electricity"}, {"02ffb866-7fb2-4d15-b761-1012cefb1360", "Embers"},
      {"cb92b597-94ca-4255-b017-0e3f42f12f9e", "Fire"},        {"2d35bcf0-e4d8-452c-97b1-3311be063130", "Flat"},
      {"55303bc4-c749-4a72-98d9-d23e68e76e18", "Flat"},        {"280c0a7a-aad8-416c-a7d2-df63d129ca70", "Flat"},
      {"cf019139-d41c-4eb0-a1d0-5cf54b0a42f3", "Highlighter"}, {"6a1cf9f9-032c-45ec-9b6e-a6680bee32e9", "HyperGrid"},
      {"dce872c2-7b49-4684-b59b-c45387949c5c", "Hypercolor"},  {"e8ef32b1-baa8-460a-9c2c-9cf8506794f5", "Hypercolor"},
      {"2f212815-f4d3-c1a4-681a-feeaf9c6dc37", "Icing"},       {"f5c336cf-5108-4b40-ade9-c687504385ab", "Ink"},
      {"c0012095-3ffd-4040-8ee1-fc180d346eaa", "Ink"},         {"ea19de07-d0c0-4484-9198-18489a3c1487", "Leaves"},
      {"2241cd32-8ba2-48a5-9ee7-2caef7e9ed62", "Light"},       {"4391aaaa-df81-4396-9e33-31e4e4930b27", "LightWire"},
      {"d381e0f5-3def-4a0d-8853-31e9200bcbda", "Lofted"},      {"429ed64a-4e97-4466-84d3-145a861ef684", "Marker"},
      {"79348357-432d-4746-8e29-0e25c112e3aa", "MatteHull"},   {"b2ffef01-eaaa-4ab5-aa64-95a2c4f5dbc6", "NeonPulse"},
      {"f72ec0e7-a844-4e38-82e3-140c44772699", "OilPaint"},    {"c515dad7-4393-4681-81ad-162ef052241b", "OilPaint"},
      {"f1114e2e-eb8d-4fde-915a-6e653b54e9f5", "Paper"},       {"759f1ebd-20cd-4720-8d41-234e0da63716", "Paper"},
      {"e0abbc80-0f80-e854-4970-8924a0863dcc", "Petal"},       {"c33714d1-b2f9-412e-bd50-1884c9d46336", "Plasma"},
      {"ad1ad437-76e2-450d-a23a-e17f8310b960", "Rainbow"},     {"faaa4d44-fcfb-4177-96be-753ac0421ba3", "ShinyHull"},
      {"70d79cca-b159-4f35-990c-f02193947fe8", "Smoke"},       {"d902ed8b-d0d1-476c-a8de-878a79e3a34c", "Snow"},
      {"accb32f5-4509-454f-93f8-1df3fd31df1b", "SoftHighlighter"}, {"cf7f0059-7aeb-53a4-2b67-c83d863a9ffa", "Spikes"},
      {"8dc4a70c-d558-4efd-a5ed-d4e860f40dc3", "Splatter"},    {"7a1c8107-50c5-4b70-9a39-421576d6617e", "Splatter"},
      {"0eb4db27-3f82-408d-b5a1-19ebd7d5b711", "Stars"},       {"44bb800a-fbc3-4592-8426-94ecb05ddec3", "Streamers"},
      {"0077f88c-d93a-42f3-b59b-b31c50cdb414", "Taffy"},       {"b468c1fb-f254-41ed-8ec9-57030bc5660c", "TaperedFlat"},
      {"c8ccb53d-ae13-45ef-8afb-b730d81394eb", "TaperedFlat"}, {"d90c6ad8-af0f-4b54-b422-e0f92abe1b3c", "TaperedMarker"},
      {"1a26b8c0-8a07-4f8a-9fac-d2ef36e0cad0", "TaperedMarker_Flat"},
      {"75b32cf0-fdd6-4d89-a64b-e2a00b247b0f", "ThickPaint"},  {"fdf0326a-c0d1-4fed-b101-9db0ff6d071f", "ThickPaint"},
      {"4391385a-df73-4396-9e33-31e4e4930b27", "Toon"},        {"a8fea537-da7c-4d4b-817f-24f074725d6d", "UnlitHull"},
      {"d229d335-c334-495a-a801-660ac8a87360", "VelvetInk"},   {"10201aa3-ebc2-42d8-84b7-2e63f6eeb8ab", "Waveform"},
      {"b67c0e81-ce6d-40a8-aeb0-ef036b081aa3", "WetPaint"},    {"dea67637-cd1a-27e4-c9b1-52f4bbcb84e5", "WetPaint"},
      {"5347acf0-a8e2-47b6-8346-30c70719d763", "WigglyGraphite"}, {"e814fef1-97fd-7194-4a2f-50c2bb918be2", "WigglyGraphite"},
      {"4391385a-cf83-4396-9e33-31e4e4930b27", "Wire"},
  };
  for (const auto& [g, name] : kBrushes)
    if (guid == g) return name;
  return "";
}

}  // namespace physketch::sketch
