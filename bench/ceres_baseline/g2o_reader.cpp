#include "g2o_reader.h"

#include <Eigen/Cholesky>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <map>
#include <unordered_map>
#include <utility>

namespace ceres_baseline {
namespace {

constexpr double kPi = 3.14159265358979323846;

double wrap_angle(double a) { return a - 2.0 * kPi * std::floor((a + kPi) / (2.0 * kPi)); }

// Whitespace tokenizer over one line with strict number parsing.
class Tokens {
 public:
  explicit Tokens(const std::string& s) : s_(s) {}

  bool next(std::string& tok) {
    while (pos_ < s_.size() && std::isspace(static_cast<unsigned char>(s_[pos_]))) ++pos_;
    if (pos_ >= s_.size()) return false;
    std::size_t b = pos_;
    while (pos_ < s_.size() && !std::isspace(static_cast<unsigned char>(s_[pos_]))) ++pos_;
    tok = s_.substr(b, pos_ - b);
    return true;
  }
  bool at_end() {
    while (pos_ < s_.size() && std::isspace(static_cast<unsigned char>(s_[pos_]))) ++pos_;
    return pos_ >= s_.size();
  }

 private:
  const std::string& s_;
  std::size_t pos_ = 0;
};

struct LineError {
  std::string why;
};

double parse_double(Tokens& tk, const char* what) {
  std::string tok;
  if (!tk.next(tok)) throw LineError{std::string("missing field '") + what + "'"};
  errno = 0;
  char* end = nullptr;
  const double v = std::strtod(tok.c_str(), &end);
  if (end == tok.c_str() || *end != '\0')
    throw LineError{std::string("field '") + what + "' is not a number: '" + tok + "'"};
  if (!std::isfinite(v))
    throw LineError{std::string("field '") + what + "' is not finite: '" + tok + "'"};
  return v;
}

long long parse_id(Tokens& tk, const char* what) {
  std::string tok;
  if (!tk.next(tok)) throw LineError{std::string("missing field '") + what + "'"};
  errno = 0;
  char* end = nullptr;
  const long long v = std::strtoll(tok.c_str(), &end, 10);
  if (end == tok.c_str() || *end != '\0' || errno == ERANGE)
    throw LineError{std::string("field '") + what + "' is not an integer id: '" + tok + "'"};
  if (v < 0) throw LineError{std::string("field '") + what + "' is a negative id: " + tok};
  return v;
}

Eigen::Quaterniond parse_quat(Tokens& tk) {
  const double qx = parse_double(tk, "qx"), qy = parse_double(tk, "qy");
  const double qz = parse_double(tk, "qz"), qw = parse_double(tk, "qw");
  Eigen::Quaterniond q(qw, qx, qy, qz);
  const double n = q.norm();
  if (!(n > 1e-9)) throw LineError{"quaternion has zero norm"};
  q.coeffs() /= n;
  return q;
}

// Reads the upper triangle (row-major) of an N×N information matrix Ω and returns its square
// root W = Lᵀ, where Ω = L·Lᵀ (Cholesky), so that |W·r|² = rᵀ·Ω·r.
template <int N>
Eigen::Matrix<double, N, N> parse_sqrt_info(Tokens& tk) {
  Eigen::Matrix<double, N, N> info;
  for (int r = 0; r < N; ++r)
    for (int c = r; c < N; ++c) {
      const double v = parse_double(tk, "information");
      info(r, c) = v;
      info(c, r) = v;
    }
  Eigen::LLT<Eigen::Matrix<double, N, N>> llt(info);
  if (llt.info() != Eigen::Success) throw LineError{"information matrix is not positive definite"};
  Eigen::Matrix<double, N, N> W = llt.matrixU();
  if (!W.allFinite() || (W.diagonal().array() <= 0.0).any())
    throw LineError{"information matrix is not positive definite"};
  return W;
}

struct RawEdge {
  long long a, b;
  int line;
};

}  // namespace

bool read_g2o(const std::string& path, Graph& g, std::string& err) {
  g = Graph{};
  std::ifstream in(path);
  if (!in) {
    err = path + ": cannot open file";
    return false;
  }

  // Vertices as read, keyed by id (SE2: x y th; SE3: t + quaternion).
  std::map<long long, std::array<double, 7>> verts;
  std::vector<RawEdge> raw;  // endpoint ids + line, parallel to g.e2 / g.e3
  std::string line, tag;
  int lineno = 0;

  auto set_dim = [&](int d) {
    if (g.dim == 0) g.dim = d;
    if (g.dim != d) throw LineError{"mixes SE(2) and SE(3) records"};
  };

  try {
    while (std::getline(in, line)) {
      ++lineno;
      if (!line.empty() && line.back() == '\r') line.pop_back();
      Tokens tk(line);
      if (!tk.next(tag)) continue;  // blank line
      if (tag[0] == '#') continue;  // comment
      if (tag == "VERTEX_SE2") {
        set_dim(2);
        const long long id = parse_id(tk, "id");
        std::array<double, 7> v{};
        v[0] = parse_double(tk, "x");
        v[1] = parse_double(tk, "y");
        v[2] = parse_double(tk, "theta");
        if (!verts.emplace(id, v).second)
          throw LineError{"duplicate vertex id " + std::to_string(id)};
      } else if (tag == "VERTEX_SE3:QUAT") {
        set_dim(3);
        const long long id = parse_id(tk, "id");
        std::array<double, 7> v{};
        v[0] = parse_double(tk, "x");
        v[1] = parse_double(tk, "y");
        v[2] = parse_double(tk, "z");
        const Eigen::Quaterniond q = parse_quat(tk);
        v[3] = q.x();
        v[4] = q.y();
        v[5] = q.z();
        v[6] = q.w();
        if (!verts.emplace(id, v).second)
          throw LineError{"duplicate vertex id " + std::to_string(id)};
      } else if (tag == "EDGE_SE2") {
        set_dim(2);
        RawEdge r{parse_id(tk, "from"), parse_id(tk, "to"), lineno};
        if (r.a == r.b) throw LineError{"edge joins a vertex to itself"};
        Edge2 e;
        e.dx = parse_double(tk, "dx");
        e.dy = parse_double(tk, "dy");
        e.dth = parse_double(tk, "dtheta");
        e.sqrt_info = parse_sqrt_info<3>(tk);
        g.e2.push_back(e);
        raw.push_back(r);
      } else if (tag == "EDGE_SE3:QUAT") {
        set_dim(3);
        RawEdge r{parse_id(tk, "from"), parse_id(tk, "to"), lineno};
        if (r.a == r.b) throw LineError{"edge joins a vertex to itself"};
        Edge3 e;
        e.t.x() = parse_double(tk, "dx");
        e.t.y() = parse_double(tk, "dy");
        e.t.z() = parse_double(tk, "dz");
        e.q = parse_quat(tk);
        e.sqrt_info = parse_sqrt_info<6>(tk);
        g.e3.push_back(e);
        raw.push_back(r);
      } else {
        throw LineError{"unknown tag '" + tag +
                        "' (this reader knows VERTEX_SE2, EDGE_SE2, "
                        "VERTEX_SE3:QUAT, EDGE_SE3:QUAT)"};
      }
      if (!tk.at_end()) throw LineError{"unexpected extra fields after the " + tag + " record"};
    }
  } catch (const LineError& e) {
    err = path + ":" + std::to_string(lineno) + ": " + e.why;
    return false;
  }
  if (in.bad()) {
    err = path + ": read error";
    return false;
  }
  if (raw.empty()) {
    err = path + ": no edges";
    return false;
  }

  g.had_vertices = !verts.empty();
  if (g.had_vertices) {
    for (const RawEdge& r : raw)
      for (long long id : {r.a, r.b})
        if (!verts.count(id)) {
          err = path + ":" + std::to_string(r.line) + ": edge refers to vertex " +
                std::to_string(id) + " which the file does not define";
          return false;
        }
  } else {
    // Edges only: the vertex set is the set of endpoints, initialised by composing odometry
    // i -> i+1 from the lowest id at the identity.
    std::map<std::pair<long long, long long>, std::size_t> first_edge;  // (a,b) -> edge index
    for (std::size_t k = 0; k < raw.size(); ++k)
      first_edge.emplace(std::make_pair(raw[k].a, raw[k].b), k);
    std::vector<long long> ids;
    for (const RawEdge& r : raw) {
      ids.push_back(r.a);
      ids.push_back(r.b);
    }
    std::sort(ids.begin(), ids.end());
    ids.erase(std::unique(ids.begin(), ids.end()), ids.end());
    std::array<double, 7> cur{};
    cur[6] = 1.0;  // identity (qw = 1 for SE3; SE2 uses 0..2)
    verts.emplace(ids[0], cur);
    for (std::size_t k = 0; k + 1 < ids.size(); ++k) {
      const long long a = ids[k], b = ids[k + 1];
      if (b != a + 1) {
        err = path + ": no vertices in the file and the edge ids are not consecutive (" +
              std::to_string(a) + " then " + std::to_string(b) +
              "): cannot initialise by composing odometry";
        return false;
      }
      bool reversed = false;
      auto it = first_edge.find({a, b});
      if (it == first_edge.end()) {
        it = first_edge.find({b, a});
        reversed = true;
      }
      if (it == first_edge.end()) {
        err = path + ": no vertices in the file and no odometry edge between " + std::to_string(a) +
              " and " + std::to_string(b) + ": cannot initialise by composing odometry";
        return false;
      }
      if (g.dim == 2) {
        const Edge2& e = g.e2[it->second];
        double dx = e.dx, dy = e.dy, dth = e.dth;
        if (reversed) {  // Z⁻¹ = (-R(θ)ᵀ t, -θ)
          const double c = std::cos(dth), s = std::sin(dth);
          dx = -(c * e.dx + s * e.dy);
          dy = -(-s * e.dx + c * e.dy);
          dth = -e.dth;
        }
        const double c = std::cos(cur[2]), s = std::sin(cur[2]);
        std::array<double, 7> nxt{};
        nxt[0] = cur[0] + c * dx - s * dy;
        nxt[1] = cur[1] + s * dx + c * dy;
        nxt[2] = wrap_angle(cur[2] + dth);
        cur = nxt;
      } else {
        const Edge3& e = g.e3[it->second];
        Eigen::Quaterniond dq = e.q;
        Eigen::Vector3d dt = e.t;
        if (reversed) {
          dq = e.q.conjugate();
          dt = -(dq * e.t);
        }
        const Eigen::Quaterniond q(cur[6], cur[3], cur[4], cur[5]);
        const Eigen::Vector3d t(cur[0], cur[1], cur[2]);
        const Eigen::Vector3d t2 = t + q * dt;
        const Eigen::Quaterniond q2 = (q * dq).normalized();
        cur = {t2.x(), t2.y(), t2.z(), q2.x(), q2.y(), q2.z(), q2.w()};
      }
      verts.emplace(b, cur);
    }
  }

  // Dense indices in ascending id order.
  std::unordered_map<long long, int> index;
  index.reserve(verts.size());
  for (const auto& kv : verts) {
    index.emplace(kv.first, static_cast<int>(g.ids.size()));
    g.ids.push_back(kv.first);
    const auto& v = kv.second;
    if (g.dim == 2) {
      g.xy.push_back({v[0], v[1]});
      g.th.push_back(v[2]);
    } else {
      g.t.push_back({v[0], v[1], v[2]});
      g.q.push_back({v[3], v[4], v[5], v[6]});
    }
  }
  for (std::size_t k = 0; k < raw.size(); ++k) {
    const int i = index.at(raw[k].a), j = index.at(raw[k].b);
    if (g.dim == 2) {
      g.e2[k].i = i;
      g.e2[k].j = j;
    } else {
      g.e3[k].i = i;
      g.e3[k].j = j;
    }
  }
  return true;
}

}  // namespace ceres_baseline
