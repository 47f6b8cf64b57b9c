#include "tools/loopd-solve/covariance_writer.h"

#include <cstdio>
#include <memory>
#include <stdexcept>

#include "robust/decorator_backend.h"
#include "robust/mh_backend.h"
#include "solvers/incremental/isam2.h"
#include "solvers/marginals/singular_information.h"
#include "solvers/problem/pose_graph_problem.h"

namespace loopd::tools {
namespace {

// isam2 itself, the one under the robust decorators, or mh's best hypothesis's: it knows which
// of its cliques were damped (a part of the graph that nothing, or only rejected closures, ties
// to the first pose).
const Isam2Backend* isam2Within(const Backend& backend) {
  const Backend* at = &backend;
  if (const auto* mh = dynamic_cast<const MhBackend*>(at)) return &mh->bestTree();
  while (const auto* decorator = dynamic_cast<const DecoratorBackend*>(at))
    at = &decorator->inner();
  return dynamic_cast<const Isam2Backend*>(at);
}

}  // namespace

void writeCovariances(const std::string& path, Backend& backend, const io::Dataset& dataset) {
  std::vector<Key> keys;
  std::vector<const io::Vertex*> vertices;
  for (const auto* list : {&dataset.poses, &dataset.landmarks})
    for (const auto& v : *list) {
      keys.push_back(vertexKey(v));
      vertices.push_back(&v);
    }
  if (const Isam2Backend* isam = isam2Within(backend))
    for (Key k : keys)
      if (!isam->marginalDetermined(k)) throw std::runtime_error(kSingularInformationMessage);
  const std::vector<Eigen::MatrixXd> cov = backend.marginals(keys);

  std::unique_ptr<FILE, int (*)(FILE*)> f(std::fopen(path.c_str(), "w"), &std::fclose);
  if (!f) throw std::runtime_error("cannot write " + path);
  std::fprintf(
      f.get(),
      "# loopd marginal covariances: KIND id, then the upper triangle (row-major) in "
      "tangent order (SE2: x y theta; SE3: x y z rx ry rz, body frame; points: x y [z])\n");
  for (size_t i = 0; i < keys.size(); ++i) {
    std::fprintf(f.get(), "%s %lld", vertices[i]->isLandmark() ? "LANDMARK" : "POSE",
                 static_cast<long long>(vertices[i]->id));
    const Eigen::MatrixXd& C = cov[i];
    for (int r = 0; r < C.rows(); ++r)
      for (int c = r; c < C.cols(); ++c) std::fprintf(f.get(), " %.17g", C(r, c));
    std::fputc('\n', f.get());
  }
  if (std::ferror(f.get())) throw std::runtime_error("error writing " + path);
}

}  // namespace loopd::tools
