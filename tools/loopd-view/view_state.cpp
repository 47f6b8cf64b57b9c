#include "tools/loopd-view/view_state.h"

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <algorithm>
#include <charconv>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <iterator>
#include <unordered_map>

#include <unistd.h>

#include "loopd/command_t.hpp"

namespace loopd::view {

namespace {

std::int64_t nowUs() {
  return std::chrono::duration_cast<std::chrono::microseconds>(
             std::chrono::system_clock::now().time_since_epoch())
      .count();
}

/// Appends a JSON number (fixed, `prec` decimals, trailing zeros trimmed); non-finite → null.
void num(std::string& o, double v, int prec = 3) {
  if (!std::isfinite(v)) {
    o += "null";
    return;
  }
  char b[64];
  auto r = std::to_chars(b, b + sizeof b, v, std::chars_format::fixed, prec);
  if (r.ec != std::errc()) {
    o += "null";
    return;
  }
  char* e = r.ptr;
  if (prec > 0) {
    while (e > b && e[-1] == '0') --e;
    if (e > b && e[-1] == '.') --e;
  }
  if (e - b == 2 && b[0] == '-' && b[1] == '0') {  // "-0"
    o += '0';
    return;
  }
  o.append(b, e);
}
void num(std::string& o, std::int64_t v) { o += std::to_string(v); }
void gnum(std::string& o, double v) {  // general format, for statistics
  if (!std::isfinite(v)) {
    o += "null";
    return;
  }
  char b[64];
  std::snprintf(b, sizeof b, "%.6g", v);
  o += b;
}

void str(std::string& o, const std::string& s) {
  o += '"';
  for (unsigned char c : s) {
    switch (c) {
      case '"':
        o += "\\\"";
        break;
      case '\\':
        o += "\\\\";
        break;
      case '\n':
        o += "\\n";
        break;
      case '\r':
        o += "\\r";
        break;
      case '\t':
        o += "\\t";
        break;
      default:
        if (c < 0x20 || c == 0x7f) {
          char b[8];
          std::snprintf(b, sizeof b, "\\u%04x", c);
          o += b;
        } else {
          o += static_cast<char>(c);  // UTF-8 passes through; invalid bytes are the page's problem
        }
    }
  }
  o += '"';
}

}  // namespace

const char* errorCodeName(int code) {
  static const char* const names[] = {"INVALID",
                                      "DECODE_FAILED",
                                      "WRONG_FINGERPRINT",
                                      "NON_FINITE",
                                      "NOT_POSITIVE_DEFINITE",
                                      "WRONG_DIMENSION",
                                      "WRONG_KEY_KIND",
                                      "UNKNOWN_KEY",
                                      "UNKNOWN_FACTOR_ID",
                                      "DUPLICATE_FACTOR_ID",
                                      "HELD_EXPIRED",
                                      "COMMAND_FAILED",
                                      "INTERNAL",
                                      "INVALID_FIELD",
                                      "LIMIT_EXCEEDED"};
  return code >= 0 && code < static_cast<int>(sizeof names / sizeof *names) ? names[code]
                                                                            : "UNKNOWN";
}

ViewState::ViewState(lcm::LCM& lcm, std::string channelPrefix, std::string lcmUrl)
    : lcm_(lcm), prefix_(std::move(channelPrefix)), url_(std::move(lcmUrl)), sub_(lcm, prefix_) {
  sub_.onEstimate([this](const client::RobotEstimate&, const loopd::estimate_t&) { touch(); });
  sub_.onCovariance([this](const loopd::covariance_t&) { touch(); });
  sub_.onStatus([this](const loopd::status_t& s) { onStatus(s); });
  sub_.onError([this](const loopd::error_t& e) { onError(e); });
  sub_.onForget([this](std::int64_t) { onForget(); });
  auto* s = lcm_.subscribeFunction(prefix_ + "FACTORS", &ViewState::factorsMsg, this);
  if (s) s->setQueueCapacity(0);
  factorsSub_ = s;
  auto* c = lcm_.subscribeFunction(prefix_ + "COMMAND", &ViewState::commandMsg, this);
  if (c) c->setQueueCapacity(0);
  commandSub_ = c;
}

ViewState::~ViewState() {
  for (void* s : {factorsSub_, commandSub_})
    if (s) lcm_.unsubscribe(static_cast<lcm::Subscription*>(s));
}

void ViewState::touch() {
  std::lock_guard<std::mutex> l(mu_);
  dirty_ = true;
  ++messages_;
  lastMessageUs_ = nowUs();
}

bool ViewState::dirty() const {
  std::lock_guard<std::mutex> l(mu_);
  return dirty_;
}

std::int64_t ViewState::messagesSeen() const {
  std::lock_guard<std::mutex> l(mu_);
  return messages_;
}

bool ViewState::statusSeen() const {
  std::lock_guard<std::mutex> l(mu_);
  return statusSeen_;
}

bool ViewState::wantsEverything() const {
  std::lock_guard<std::mutex> l(mu_);
  return wantEverything_;
}

void ViewState::requestEverything() {
  std::lock_guard<std::mutex> l(mu_);
  wantEverything_ = false;
  for (const auto cmd : {loopd::command_t::REQUEST_ESTIMATE, loopd::command_t::REQUEST_STATUS}) {
    loopd::command_t c{};
    c.utime = nowUs();
    c.sender = "loopd-view";
    c.request_id = (static_cast<std::int64_t>(::getpid()) << 20) + (++requestId_);
    c.command = cmd;
    c.argument = "";
    c.num_keys = 0;
    lcm_.publish(prefix_ + "COMMAND", &c);
  }
}

namespace {
constexpr std::size_t kMaxPendingBatches = 10000;  // unsettled (the server never saw them?)
constexpr std::size_t kMaxClosures = 1000000;      // a bound on what a flood can make us keep
constexpr std::size_t kMaxSenders = 10000;
constexpr std::size_t kMaxSequencesAbove = 100000;  // out of order, per sender
}  // namespace

bool ViewState::SeenSequences::insert(std::int64_t sequence) {
  if (sequence <= contiguous || !above.insert(sequence).second) return false;
  while (!above.empty() && *above.begin() == contiguous + 1) {
    ++contiguous;
    above.erase(above.begin());
  }
  if (above.size() > kMaxSequencesAbove) above.clear();  // less strict, bounded
  return true;
}

void ViewState::factorsMsg(const lcm::ReceiveBuffer*, const std::string&,
                           const loopd::factor_batch_t* m, ViewState* self) {
  std::lock_guard<std::mutex> l(self->mu_);
  ++self->factorBatches_;
  self->trackBatch(*m);
}

void ViewState::trackBatch(const loopd::factor_batch_t& m) {
  // The server refuses a batch without a usable identity, and ignores one it has seen.
  if (m.sender.empty() || m.sender.size() > 63 || m.sequence < 1) return;
  const BatchName name{m.sender, m.sequence};
  if (seenBatches_.size() >= kMaxSenders) seenBatches_.clear();  // less strict, bounded
  if (!seenBatches_[m.sender].insert(m.sequence)) {
    ++duplicates_;
    return;
  }
  PendingBatch b;
  b.name = name;
  for (const auto& f : m.factors) {
    if (f.role != loopd::factor_t::ROLE_LOOP_CLOSURE || f.keys.size() != 2) continue;
    if (f.keys[0].kind != loopd::key_t::POSE || f.keys[1].kind != loopd::key_t::POSE) continue;
    b.closures.emplace_back(f.id, Closure{f.keys[0], f.keys[1]});
  }
  for (const auto id : m.remove_ids) {
    const auto it = closures_.find({m.sender, id});
    if (it == closures_.end()) continue;
    b.removed.emplace_back(id, it->second);
    closures_.erase(it);
  }
  if (b.closures.empty() && b.removed.empty()) return;  // nothing to draw or bring back
  const std::uint64_t arrival = ++arrivals_;
  for (const auto& [id, c] : b.closures) pendingByClosure_[{m.sender, id}].insert(arrival);
  pendingByBatch_[name] = arrival;
  pending_.emplace(arrival, std::move(b));
  if (pending_.size() > kMaxPendingBatches) dropPending(pending_.begin()->first);
}

void ViewState::dropPending(std::uint64_t arrival) {
  const auto it = pending_.find(arrival);
  if (it == pending_.end()) return;
  for (const auto& [id, c] : it->second.closures) {
    const auto ix = pendingByClosure_.find({it->second.name.first, id});
    if (ix == pendingByClosure_.end()) continue;
    ix->second.erase(arrival);
    if (ix->second.empty()) pendingByClosure_.erase(ix);
  }
  pendingByBatch_.erase(it->second.name);
  pending_.erase(it);
}

/// The server decided on `closure`: the oldest unsettled batch carrying it was accepted (a
/// later one reusing the id is refused with DUPLICATE_FACTOR_ID while it lives).
void ViewState::adoptBatchWith(const FactorName& closure) {
  if (closures_.count(closure)) return;  // a decision about a closure already placed
  const auto ix = pendingByClosure_.find(closure);
  if (ix == pendingByClosure_.end()) return;  // sent before the view started: unmapped
  const std::uint64_t arrival = *ix->second.begin();
  const PendingBatch& b = pending_.at(arrival);
  for (const auto& [id, c] : b.closures)
    if (closures_.size() < kMaxClosures) closures_[{b.name.first, id}] = c;
  dropPending(arrival);
}

void ViewState::refuseBatch(const BatchName& batch) {
  const auto it = pendingByBatch_.find(batch);
  if (it == pendingByBatch_.end()) return;
  const PendingBatch& b = pending_.at(it->second);
  for (const auto& [id, c] : b.removed) closures_.emplace(FactorName{b.name.first, id}, c);
  dropPending(it->second);
}

/// A complete listing names every uncertain factor the server has: the rest are gone.
void ViewState::pruneClosuresWithoutDecision() {
  for (auto it = closures_.begin(); it != closures_.end();)
    it = decisions_.decisions().count(it->first) ? std::next(it) : closures_.erase(it);
}

void ViewState::commandMsg(const lcm::ReceiveBuffer*, const std::string&, const loopd::command_t* m,
                           ViewState* self) {
  if (m->command != loopd::command_t::RESET) return;
  std::lock_guard<std::mutex> l(self->mu_);
  // Senders may start their sequences again at once, before the server's status says the
  // graph is gone: their batches are not duplicates.
  self->seenBatches_.clear();
  self->resetMark_ = self->arrivals_;
}

void ViewState::onForget() {
  std::lock_guard<std::mutex> l(mu_);
  dirty_ = true;
  closures_.clear();
  decisions_.clear();
  seenBatches_.clear();
  // Batches from before a RESET command belong to the dropped graph; later ones (and all, after
  // a restart, which no command announces) may still be settled by the server.
  while (!pending_.empty() && pending_.begin()->first <= resetMark_)
    dropPending(pending_.begin()->first);
  resetMark_ = 0;
  for (auto& [arrival, b] : pending_) b.removed.clear();
  wantEverything_ = true;
}

void ViewState::onStatus(const loopd::status_t& s) {
  std::lock_guard<std::mutex> l(mu_);
  dirty_ = true;
  ++messages_;
  ++statusMsgs_;
  lastMessageUs_ = nowUs();
  statusSeen_ = true;
  // Every update publishes a status: a gap in update_seq is a lost one, and with it decisions.
  if (lastStatusSeq_ > 0 && s.update_seq > lastStatusSeq_ + 1) wantEverything_ = true;
  lastStatusSeq_ = std::max(lastStatusSeq_, s.update_seq);
  applyDecisions(s);
}

void ViewState::applyDecisions(const loopd::status_t& s) {
  switch (decisions_.apply(s)) {
    case client::DecisionTable::Applied::Changes:
      for (const auto& d : s.decisions)
        if (!d.ambiguous) adoptBatchWith({d.sender, d.factor_id});
      break;
    case client::DecisionTable::Applied::PartOfListing:
      break;
    case client::DecisionTable::Applied::ListingComplete:
      pruneClosuresWithoutDecision();
      for (const auto& [name, d] : decisions_.decisions())
        if (!d.ambiguous) adoptBatchWith(name);
      break;
    case client::DecisionTable::Applied::ListingBroken:
      wantEverything_ = true;  // a chunk was lost: ask for the listing again
      break;
  }
}

void ViewState::onError(const loopd::error_t& e) {
  std::lock_guard<std::mutex> l(mu_);
  dirty_ = true;
  ++messages_;
  lastMessageUs_ = nowUs();
  ++errors_;
  ++errorsByCode_[e.code];
  recentErrors_.push_back(e);
  while (recentErrors_.size() > 20) recentErrors_.pop_front();
  // A batch is refused whole; command errors carry a request id and no sequence.
  if (e.request_id == 0 && e.sequence >= 1) refuseBatch({e.sender, e.sequence});
}

std::string ViewState::renderJson(std::uint64_t seq) {
  // Copies from the subscriber first (its own lock), then ours.
  const auto robots = sub_.all();
  const auto covs = sub_.latestCovariances();
  const loopd::status_t st = sub_.lastStatus();
  std::lock_guard<std::mutex> l(mu_);
  dirty_ = false;

  std::string o;
  std::size_t estimate = 256;
  for (const auto& [r, t] : robots) estimate += t.poses.size() * 24 + t.landmarks.size() * 24;
  o.reserve(estimate + closures_.size() * 24);
  o += "{\"seq\":";
  num(o, static_cast<std::int64_t>(seq));
  o += ",\"time_us\":";
  num(o, nowUs());
  o += ",\"prefix\":";
  str(o, prefix_);
  o += ",\"lcm_url\":";
  str(o, url_);
  o += ",\"messages\":";
  num(o, messages_);
  o += ",\"factor_batches\":";
  num(o, factorBatches_);
  o += ",\"last_message_us\":";
  num(o, lastMessageUs_);

  // Status.
  o += ",\"status\":";
  if (!statusSeen_) {
    o += "null";
  } else {
    o += "{\"utime\":";
    num(o, st.utime);
    o += ",\"update_seq\":";
    num(o, st.update_seq);
    o += ",\"solver\":";
    str(o, st.solver);
    o += ",\"converged\":";
    o += st.converged ? "true" : "false";
    const std::pair<const char*, std::int64_t> ints[] = {
        {"robots", st.robots},
        {"robots_in_common_frame", st.robots_in_common_frame},
        {"poses", st.poses},
        {"landmarks", st.landmarks},
        {"factors", st.factors},
        {"loop_closures", st.loop_closures},
        {"loop_closures_rejected", st.loop_closures_rejected},
        {"ambiguous", st.ambiguous},
        {"queue_depth", st.queue_depth},
        {"batches_accepted", st.batches_accepted},
        {"batches_rejected", st.batches_rejected},
        {"batches_duplicate", st.batches_duplicate},
        {"batches_held", st.batches_held},
        {"batches_expired", st.batches_expired},
        {"sender_gaps", st.num_sender_gaps},
        {"live_hypotheses", st.live_hypotheses},
    };
    for (const auto& [k, v] : ints) {
      o += ",\"";
      o += k;
      o += "\":";
      num(o, v);
    }
    o += ",\"last_update_ms\":";
    gnum(o, st.last_update_ms);
    o += ",\"mean_update_ms\":";
    gnum(o, st.mean_update_ms);
    o += ",\"chi2\":";
    gnum(o, st.chi2);
    o += "}";
  }

  // Robots: positions only (x y, or x y z), in index order; the page projects them.
  std::map<std::int32_t, std::unordered_map<std::int64_t, std::int64_t>> ordinal;
  o += ",\"robots\":[";
  bool first = true;
  for (const auto& [r, t] : robots) {
    if (t.poses.empty() && t.landmarks.empty()) continue;
    if (!first) o += ',';
    first = false;
    const int d = t.se3 ? 3 : 2;
    o += "{\"id\":";
    num(o, std::int64_t{r});
    o += ",\"frame\":";
    num(o, std::int64_t{t.frameRobot});
    o += ",\"common\":";
    o += t.commonFrame ? "true" : "false";
    o += ",\"se3\":";
    o += t.se3 ? "true" : "false";
    o += ",\"update_seq\":";
    num(o, t.updateSeq);
    o += ",\"first\":";
    num(o, t.poses.empty() ? std::int64_t{-1} : t.poses.begin()->first);
    o += ",\"last\":";
    num(o, t.poses.empty() ? std::int64_t{-1} : t.poses.rbegin()->first);
    o += ",\"d\":";
    num(o, std::int64_t{d});
    o += ",\"p\":[";
    auto& ord = ordinal[r];
    ord.reserve(t.poses.size());
    std::int64_t k = 0;
    for (const auto& [idx, v] : t.poses) {
      if (k) o += ',';
      ord[idx] = k++;
      for (int i = 0; i < d; ++i) {
        if (i) o += ',';
        num(o, i < static_cast<int>(v.size()) ? v[static_cast<std::size_t>(i)] : 0.0);
      }
    }
    o += "],\"heading\":";
    if (!t.poses.empty() && !t.se3 && t.poses.rbegin()->second.size() >= 3)
      num(o, t.poses.rbegin()->second[2], 4);
    else
      o += "null";
    o += ",\"l\":[";
    bool lf = true;
    for (const auto& [idx, v] : t.landmarks) {
      for (int i = 0; i < d; ++i) {
        if (!lf) o += ',';
        lf = false;
        num(o, i < static_cast<int>(v.size()) ? v[static_cast<std::size_t>(i)] : 0.0);
      }
    }
    o += "]}";
  }
  o += ']';

  // 2σ ellipses: the latest pose's position covariance, rotated from the body frame (the
  // perturbation is on the right) into the estimate's frame: Σ_w = R Σ_b Rᵀ; 3×3 upper triangle.
  o += ",\"covariances\":[";
  first = true;
  for (const auto& [r, ic] : covs) {
    const auto& [index, c] = ic;
    auto rt = robots.find(r);
    if (rt == robots.end()) continue;
    auto pt = rt->second.poses.find(index);
    if (pt == rt->second.poses.end()) continue;
    const auto& v = pt->second;
    Eigen::Matrix3d sb = Eigen::Matrix3d::Zero(), R = Eigen::Matrix3d::Identity();
    Eigen::Vector3d p = Eigen::Vector3d::Zero();
    if (!rt->second.se3 && c.size() == 9 && v.size() >= 3) {
      for (int i = 0; i < 2; ++i)
        for (int j = 0; j < 2; ++j) sb(i, j) = c[static_cast<std::size_t>(i * 3 + j)];
      R.topLeftCorner<2, 2>() = Eigen::Rotation2Dd(v[2]).toRotationMatrix();
      p << v[0], v[1], 0.0;
    } else if (rt->second.se3 && c.size() == 36 && v.size() >= 7) {
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) sb(i, j) = c[static_cast<std::size_t>(i * 6 + j)];
      Eigen::Quaterniond q(v[6], v[3], v[4], v[5]);
      if (q.norm() < 1e-9) continue;
      R = q.normalized().toRotationMatrix();
      p << v[0], v[1], v[2];
    } else {
      continue;
    }
    const Eigen::Matrix3d sw = R * sb * R.transpose();
    if (!sw.allFinite()) continue;
    if (!first) o += ',';
    first = false;
    o += "{\"robot\":";
    num(o, std::int64_t{r});
    o += ",\"index\":";
    num(o, index);
    o += ",\"pos\":[";
    for (int i = 0; i < 3; ++i) {
      if (i) o += ',';
      num(o, p[i]);
    }
    o += "],\"c\":[";
    const int ij[6][2] = {{0, 0}, {0, 1}, {0, 2}, {1, 1}, {1, 2}, {2, 2}};
    for (int i = 0; i < 6; ++i) {
      if (i) o += ',';
      gnum(o, sw(ij[i][0], ij[i][1]));
    }
    o += "]}";
  }
  o += ']';

  // Accepted loop closures with both ends in the estimate: [robotA, ordinalA, robotB, ordinalB,
  // state, weight]; state 1 accepted, 0 rejected (as a robust solver judges it). Closures
  // still waiting for the server are counted (pending), not drawn; decisions whose factor was
  // never seen on the factor channel (the view started late) have no endpoints: counted only.
  std::int64_t accepted = 0, rejected = 0, unplaced = 0, unmapped = 0, unmappedRejected = 0,
               pendingClosures = 0;
  o += ",\"links\":[";
  first = true;
  for (const auto& [name, cl] : closures_) {
    const auto d = decisions_.decisions().find(name);
    if (d == decisions_.decisions().end()) continue;  // pruned with the next complete listing
    auto ra = ordinal.find(cl.a.robot), rb = ordinal.find(cl.b.robot);
    if (ra == ordinal.end() || rb == ordinal.end()) {
      ++unplaced;
      continue;
    }
    auto ia = ra->second.find(cl.a.index), ib = rb->second.find(cl.b.index);
    if (ia == ra->second.end() || ib == rb->second.end()) {
      ++unplaced;
      continue;
    }
    const int state = d->second.accepted ? 1 : 0;
    (state == 1 ? accepted : rejected)++;
    if (!first) o += ',';
    first = false;
    o += '[';
    num(o, std::int64_t{cl.a.robot});
    o += ',';
    num(o, ia->second);
    o += ',';
    num(o, std::int64_t{cl.b.robot});
    o += ',';
    num(o, ib->second);
    o += ',';
    num(o, std::int64_t{state});
    o += ',';
    num(o, d->second.weight, 3);
    o += ']';
  }
  o += ']';
  std::int64_t closureDecisions = 0;  // ambiguous measurements have no single pair of ends
  for (const auto& [name, d] : decisions_.decisions()) {
    if (d.ambiguous) continue;
    ++closureDecisions;
    if (!closures_.count(name)) {
      ++unmapped;
      unmappedRejected += d.accepted ? 0 : 1;
    }
  }
  for (const auto& [arrival, b] : pending_)
    pendingClosures += static_cast<std::int64_t>(b.closures.size());
  o += ",\"link_counts\":{\"accepted\":";
  num(o, accepted);
  o += ",\"rejected\":";
  num(o, rejected);
  o += ",\"pending\":";
  num(o, pendingClosures);
  o += ",\"unplaced\":";
  num(o, unplaced);
  o += ",\"decisions\":";
  num(o, closureDecisions);
  o += ",\"unmapped_decisions\":";
  num(o, unmapped);
  o += ",\"unmapped_rejected\":";
  num(o, unmappedRejected);
  o += ",\"duplicate_batches\":";
  num(o, duplicates_);
  o += '}';

  // Errors.
  o += ",\"errors\":{\"count\":";
  num(o, errors_);
  o += ",\"by_code\":{";
  first = true;
  for (const auto& [code, n] : errorsByCode_) {
    if (!first) o += ',';
    first = false;
    str(o, errorCodeName(code));
    o += ':';
    num(o, n);
  }
  o += "},\"recent\":[";
  first = true;
  for (auto it = recentErrors_.rbegin(); it != recentErrors_.rend(); ++it) {
    if (!first) o += ',';
    first = false;
    o += "{\"utime\":";
    num(o, it->utime);
    o += ",\"code\":";
    str(o, errorCodeName(it->code));
    o += ",\"sender\":";
    str(o, it->sender);
    o += ",\"factor_id\":";
    num(o, it->factor_id);
    o += ",\"reason\":";
    str(o, it->reason.substr(0, 300));
    o += '}';
  }
  o += "]}}";
  return o;
}

}  // namespace loopd::view
