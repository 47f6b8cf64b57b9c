#pragma once
// Copy-on-write numeric storage for Bayes-tree cliques. Copying a backend (a hypothesis
// branching in robust/mh_backend.h) shares every clique's conditional instead of copying it;
// the first re-elimination of a clique in one copy gives that copy fresh storage, so the
// cliques a branch never touches stay one object for all hypotheses.
#include <cstddef>
#include <memory>

namespace loopd {

class SharedBuffer {
 public:
  /// Storage for n doubles that this owner alone may write; the contents are undefined when
  /// it had to be (re)allocated (callers overwrite what they use).
  double* writable(size_t n) {
    if (n > capacity_ || 2 * n + 256 < capacity_ || p_.use_count() > 1) {
      p_.reset(new double[n], std::default_delete<double[]>());
      capacity_ = n;
    }
    return p_.get();
  }
  /// Write access to storage already made writable (elimination writes in several steps).
  double* data() { return p_.get(); }
  const double* data() const { return p_.get(); }
  size_t capacity() const { return capacity_; }
  bool shared() const { return p_.use_count() > 1; }
  void release() {
    p_.reset();
    capacity_ = 0;
  }

 private:
  std::shared_ptr<double> p_;
  size_t capacity_ = 0;
};

}  // namespace loopd
