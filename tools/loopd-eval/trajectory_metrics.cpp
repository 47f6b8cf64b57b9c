#include "tools/loopd-eval/trajectory_metrics.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <map>
#include <sstream>
#include <stdexcept>
#include <unordered_map>
#include <unordered_set>

#include "solvers/problem/pose_graph_problem.h"

namespace loopd::tools {

namespace {

Eigen::Isometry3d poseOf(const io::Vertex& v) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  if (v.type == io::VertexType::SE2) {
    T.linear() = Eigen::AngleAxisd(v.value[2], Eigen::Vector3d::UnitZ()).toRotationMatrix();
    T.translation() = Eigen::Vector3d(v.value[0], v.value[1], 0.0);
  } else {
    Eigen::Quaterniond q(v.value[6], v.value[3], v.value[4], v.value[5]);
    T.linear() = q.normalized().toRotationMatrix();
    T.translation() = Eigen::Vector3d(v.value[0], v.value[1], v.value[2]);
  }
  return T;
}

double rotationAngle(const Eigen::Matrix3d& R) {
  const double c = std::clamp((R.trace() - 1.0) * 0.5, -1.0, 1.0);
  return std::acos(c);
}

}  // namespace

TrajectoryErrors trajectoryErrors(const io::Dataset& reference, const io::Dataset& estimate) {
  const std::string refName = reference.path.empty() ? "the reference" : reference.path;
  const std::string estName = estimate.path.empty() ? "the estimate" : estimate.path;
  std::map<std::int64_t, const io::Vertex*> ref;
  for (const auto& v : reference.poses) ref[v.id] = &v;
  std::vector<std::int64_t> ids;
  std::map<std::int64_t, const io::Vertex*> est;
  for (const auto& v : estimate.poses) est[v.id] = &v;
  // Scoring only the shared poses would hide a partial estimate or another dataset's.
  size_t missing = 0, extra = 0;
  std::int64_t firstMissing = 0, firstExtra = 0;
  for (const auto& [id, v] : ref) {
    if (est.count(id))
      ids.push_back(id);
    else if (missing++ == 0)
      firstMissing = id;
  }
  for (const auto& [id, v] : est)
    if (!ref.count(id) && extra++ == 0) firstExtra = id;
  if (missing)
    throw std::invalid_argument(estName + " lacks " + std::to_string(missing) + " of the " +
                                std::to_string(ref.size()) + " poses of " + refName +
                                " (first missing: id " + std::to_string(firstMissing) + ")");
  if (extra)
    throw std::invalid_argument(estName + " has " + std::to_string(extra) + " poses " + refName +
                                " lacks (first: id " + std::to_string(firstExtra) +
                                "): not an estimate of the same graph");
  if (ids.size() < 2) throw std::invalid_argument("reference and estimate share < 2 poses");
  const bool is3d = ref[ids[0]]->type == io::VertexType::SE3;
  auto dim = [](const io::Vertex* v) { return v->type == io::VertexType::SE3 ? "3D" : "2D"; };
  for (std::int64_t id : ids) {
    const bool r3 = ref[id]->type == io::VertexType::SE3, e3 = est[id]->type == io::VertexType::SE3;
    if (r3 != e3)
      throw std::invalid_argument("reference and estimate mix 2D and 3D poses: pose " +
                                  std::to_string(id) + " is " + dim(ref[id]) + " in " + refName +
                                  ", " + dim(est[id]) + " in " + estName);
    if (r3 != is3d)
      throw std::invalid_argument(refName + " mixes 2D and 3D poses: pose " +
                                  std::to_string(ids[0]) + " is " + dim(ref[ids[0]]) + ", pose " +
                                  std::to_string(id) + " " + dim(ref[id]));
  }

  const int n = static_cast<int>(ids.size());
  std::vector<Eigen::Isometry3d> R(n), E(n);
  for (int i = 0; i < n; ++i) R[i] = poseOf(*ref[ids[i]]), E[i] = poseOf(*est[ids[i]]);

  TrajectoryErrors out;
  out.poses = n;
  const int d = is3d ? 3 : 2;
  Eigen::MatrixXd src(d, n), dst(d, n);
  for (int i = 0; i < n; ++i) {
    src.col(i) = E[i].translation().head(d);
    dst.col(i) = R[i].translation().head(d);
  }
  const Eigen::MatrixXd T = Eigen::umeyama(src, dst, false);
  const Eigen::MatrixXd A = T.topLeftCorner(d, d);
  const Eigen::VectorXd b = T.topRightCorner(d, 1);
  double sum = 0.0;
  for (int i = 0; i < n; ++i) {
    const double e = (A * src.col(i) + b - dst.col(i)).norm();
    sum += e * e;
    out.ateMax = std::max(out.ateMax, e);
  }
  out.ateRmse = std::sqrt(sum / n);

  double st = 0.0, sr = 0.0;
  for (int i = 0; i + 1 < n; ++i) {
    const Eigen::Isometry3d dr = R[i].inverse() * R[i + 1];
    const Eigen::Isometry3d de = E[i].inverse() * E[i + 1];
    const Eigen::Isometry3d err = dr.inverse() * de;
    st += err.translation().norm();
    sr += rotationAngle(err.linear());
    ++out.rpePairs;
  }
  if (out.rpePairs > 0) {
    out.rpeTrans = st / out.rpePairs;
    out.rpeRotDeg = sr / out.rpePairs * 180.0 / M_PI;
  }
  return out;
}

DecisionScores scoreRejections(const std::vector<std::int64_t>& rejected,
                               const std::vector<std::int64_t>& outliers) {
  const std::unordered_set<std::int64_t> truth(outliers.begin(), outliers.end());
  const std::unordered_set<std::int64_t> rej(rejected.begin(), rejected.end());
  DecisionScores s;
  for (std::int64_t id : rej) (truth.count(id) ? s.truePositives : s.falsePositives)++;
  for (std::int64_t id : truth)
    if (!rej.count(id)) ++s.falseNegatives;
  if (!rej.empty()) s.precision = static_cast<double>(s.truePositives) / rej.size();
  if (!truth.empty()) s.recall = static_cast<double>(s.truePositives) / truth.size();
  return s;
}

double inlierChi2(const io::Dataset& graph, const io::Dataset& estimate,
                  const std::vector<std::int64_t>& outliers) {
  io::Dataset g = graph;
  std::unordered_map<std::int64_t, const io::Vertex*> poses, landmarks;
  for (const auto& v : estimate.poses) poses[v.id] = &v;
  for (const auto& v : estimate.landmarks) landmarks[v.id] = &v;
  for (auto& v : g.poses) {
    auto it = poses.find(v.id);
    if (it == poses.end())
      throw std::invalid_argument("estimate lacks pose " + std::to_string(v.id));
    v.value = it->second->value;
  }
  for (auto& v : g.landmarks) {
    auto it = landmarks.find(v.id);
    if (it != landmarks.end()) v.value = it->second->value;
  }
  const PoseGraphProblem p = buildProblem(g);
  const std::unordered_set<std::int64_t> skip(outliers.begin(), outliers.end());
  double chi2 = 0.0;
  for (const auto& f : p.graph.factors()) {
    const auto id = static_cast<std::int64_t>(f->id());
    if (id < static_cast<std::int64_t>(g.edges.size()) && !skip.count(id))
      chi2 += f->chi2(p.initial);
  }
  return chi2;
}

namespace {

// A strict reader of one JSON document (RFC 8259) that keeps the spans of its top-level
// object's members: enough to tell a truth or stats file from anything else.
class JsonDocument {
 public:
  explicit JsonDocument(const std::string& text) : s_(text) {
    space();
    if (p_ >= s_.size() || s_[p_] != '{') fail("not a JSON object");
    object(0, true);
    space();
    if (p_ != s_.size()) fail("not JSON: text after the object");
  }
  const std::string* member(const std::string& key) const {
    auto it = members_.find(key);
    return it == members_.end() ? nullptr : &it->second;
  }

 private:
  [[noreturn]] void fail(const std::string& what) const {
    const size_t at = std::min(p_, s_.size());
    const size_t line = 1 + static_cast<size_t>(std::count(s_.begin(), s_.begin() + at, '\n'));
    throw std::runtime_error(what + " (line " + std::to_string(line) + ")");
  }
  void space() {
    while (p_ < s_.size() && (s_[p_] == ' ' || s_[p_] == '\t' || s_[p_] == '\n' || s_[p_] == '\r'))
      ++p_;
  }
  bool eat(char c) {
    space();
    if (p_ < s_.size() && s_[p_] == c) return ++p_, true;
    return false;
  }
  void expect(char c, const char* where) {
    if (!eat(c)) fail(std::string("not JSON: expected '") + c + "' " + where);
  }
  void value(int depth) {
    if (depth > 64) fail("not JSON: nested too deeply");
    space();
    if (p_ >= s_.size()) fail("not JSON: unexpected end");
    const char c = s_[p_];
    if (c == '{')
      object(depth + 1, false);
    else if (c == '[')
      array(depth + 1);
    else if (c == '"')
      string();
    else if (c == '-' || (c >= '0' && c <= '9'))
      number();
    else if (!literal("true") && !literal("false") && !literal("null"))
      fail("not JSON: unexpected character");
  }
  bool literal(const char* word) {
    const size_t n = std::strlen(word);
    if (s_.compare(p_, n, word) != 0) return false;
    p_ += n;
    return true;
  }
  void number() {
    if (s_[p_] == '-') ++p_;
    auto digits = [&] {
      const size_t from = p_;
      while (p_ < s_.size() && s_[p_] >= '0' && s_[p_] <= '9') ++p_;
      if (p_ == from) fail("not JSON: malformed number");
      return p_ - from;
    };
    const size_t first = p_;
    if (digits() > 1 && s_[first] == '0') fail("not JSON: number with a leading zero");
    if (p_ < s_.size() && s_[p_] == '.') ++p_, digits();
    if (p_ < s_.size() && (s_[p_] == 'e' || s_[p_] == 'E')) {
      ++p_;
      if (p_ < s_.size() && (s_[p_] == '+' || s_[p_] == '-')) ++p_;
      digits();
    }
  }
  std::string string() {
    ++p_;  // the opening quote
    std::string out;
    while (p_ < s_.size() && s_[p_] != '"') {
      const char c = s_[p_++];
      if (static_cast<unsigned char>(c) < 0x20) fail("not JSON: control character in a string");
      if (c == '\\') {
        if (p_ >= s_.size()) break;
        const char e = s_[p_++];
        if (e == 'u') {
          for (int k = 0; k < 4; ++k, ++p_)
            if (p_ >= s_.size() || !std::isxdigit(static_cast<unsigned char>(s_[p_])))
              fail("not JSON: malformed \\u escape");
        } else if (std::strchr("\"\\/bfnrt", e) == nullptr || e == '\0') {
          fail("not JSON: unknown escape in a string");
        }
        out += e;  // only keys are kept, and only compared with plain names
      } else {
        out += c;
      }
    }
    if (p_ >= s_.size()) fail("not JSON: unterminated string");
    ++p_;
    return out;
  }
  void array(int depth) {
    ++p_;
    if (eat(']')) return;
    do value(depth);
    while (eat(','));
    expect(']', "after an array element");
  }
  void object(int depth, bool top) {
    ++p_;
    if (eat('}')) return;
    do {
      space();
      if (p_ >= s_.size() || s_[p_] != '"') fail("not JSON: expected a quoted key");
      const std::string key = string();
      expect(':', "after a key");
      space();
      const size_t from = p_;
      value(depth);
      if (top && !members_.emplace(key, s_.substr(from, p_ - from)).second)
        fail("duplicate key \"" + key + "\"");
    } while (eat(','));
    expect('}', "after an object member");
  }

  const std::string& s_;
  size_t p_ = 0;
  std::map<std::string, std::string> members_;
};

// A member's value as an array of integers (JSON integers: no fraction, no exponent).
std::vector<std::int64_t> intArray(const std::string& value, const std::string& key) {
  const std::string what = "\"" + key + "\" is not an array of integers";
  if (value.empty() || value[0] != '[') throw std::runtime_error(what + ": " + value.substr(0, 40));
  std::vector<std::int64_t> out;
  size_t p = 1;
  auto space = [&] {
    while (p < value.size() && std::isspace(static_cast<unsigned char>(value[p]))) ++p;
  };
  space();
  if (value[p] == ']') return out;
  for (;;) {
    space();
    const size_t from = p;
    if (p < value.size() && value[p] == '-') ++p;
    while (p < value.size() && std::isdigit(static_cast<unsigned char>(value[p]))) ++p;
    size_t to = p;
    while (to < value.size() && value[to] != ',' && value[to] != ']' &&
           !std::isspace(static_cast<unsigned char>(value[to])))
      ++to;
    const std::string tok = value.substr(from, to - from);
    if (to != p || p == from || tok == "-")
      throw std::runtime_error(what + ": element " + std::to_string(out.size()) + " is " + tok);
    errno = 0;
    const long long v = std::strtoll(tok.c_str(), nullptr, 10);
    if (errno == ERANGE)
      throw std::runtime_error("\"" + key + "\": " + tok + " does not fit a 64-bit integer");
    out.push_back(v);
    space();
    if (value[p] == ']') return out;
    ++p;  // ',' (the document was checked as JSON)
  }
}

}  // namespace

std::vector<std::int64_t> jsonIntArray(const std::string& json, const std::string& key) {
  const JsonDocument doc(json);
  const std::string* value = doc.member(key);
  return value ? intArray(*value, key) : std::vector<std::int64_t>{};
}

bool jsonHasKey(const std::string& json, const std::string& key) {
  return JsonDocument(json).member(key) != nullptr;
}

std::vector<std::int64_t> readIntArray(const std::string& path, const std::string& key,
                                       std::int64_t minValue, const std::string& kind) {
  const std::string text = readTextFile(path);
  try {
    const JsonDocument doc(text);
    const std::string* value = doc.member(key);
    if (!value)
      throw std::runtime_error("no \"" + key + "\" array" +
                               (kind.empty() ? std::string() : " (not " + kind + "?)"));
    std::vector<std::int64_t> out = intArray(*value, key);
    for (std::int64_t v : out)
      if (v < minValue)
        throw std::runtime_error("\"" + key + "\" holds " + std::to_string(v) + ", below " +
                                 std::to_string(minValue));
    return out;
  } catch (const std::runtime_error& e) {
    throw std::runtime_error(path + ": " + e.what());
  }
}

double jsonNumber(const std::string& json, const std::string& key, double fallback) {
  const std::string quoted = "\"" + key + "\"";
  size_t p = json.find(quoted);
  if (p == std::string::npos) return fallback;
  p = json.find(':', p + quoted.size());
  if (p == std::string::npos) return fallback;
  try {
    return std::stod(json.substr(p + 1));
  } catch (const std::exception&) {
    return fallback;
  }
}

io::Dataset readVertices(const std::string& path) {
  std::istringstream in(readTextFile(path));
  io::Dataset d;
  d.path = path;
  d.format = "g2o";
  d.hadVertices = true;
  std::string line;
  int lineNo = 0;
  std::unordered_map<std::int64_t, int> poseLines, landmarkLines;
  while (std::getline(in, line)) {
    ++lineNo;
    std::istringstream ls(line);
    std::string tag;
    if (!(ls >> tag)) continue;
    io::Vertex v;
    int n = 0;
    if (tag == "VERTEX_SE2")
      v.type = io::VertexType::SE2, n = 3;
    else if (tag == "VERTEX_SE3:QUAT")
      v.type = io::VertexType::SE3, n = 7;
    else if (tag == "VERTEX_XY")
      v.type = io::VertexType::Point2, n = 2;
    else if (tag == "VERTEX_TRACKXYZ")
      v.type = io::VertexType::Point3, n = 3;
    else
      continue;
    ls >> v.id;
    for (int k = 0; k < n; ++k) ls >> v.value[k];
    if (!ls) throw std::runtime_error(path + ":" + std::to_string(lineNo) + ": malformed " + tag);
    v.line = lineNo;
    auto& seen = v.isLandmark() ? landmarkLines : poseLines;
    const auto [it, fresh] = seen.emplace(v.id, lineNo);
    if (!fresh)
      throw std::runtime_error(path + ":" + std::to_string(lineNo) + ": " +
                               (v.isLandmark() ? "landmark" : "pose") + " id " +
                               std::to_string(v.id) + " given twice (first on line " +
                               std::to_string(it->second) + ")");
    if (v.isLandmark())
      d.landmarks.push_back(v);
    else
      d.poses.push_back(v);
    if (v.type == io::VertexType::SE3) d.is3d = true;
  }
  return d;
}

std::string readTextFile(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw std::runtime_error("cannot read " + path);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

}  // namespace loopd::tools
