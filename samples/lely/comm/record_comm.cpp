// record_comm.cpp - record SYNC, PDO and EMCY traffic of the Lely CANopen stack
// where Lely behaves differently from CANopenNode (SPEC_COMM §9: Lely applies
// 1029h only to EMCY codes 81xxh, and it has no SYNC consumer timeout).
//
// The same bus, connectors, recorder and master as ../record.cpp (see the
// comment there and ../recorder.hpp): one Lely CiA 302 master (node 1, from
// ../master.dcf and the concise DCFs ../slaveN.bin made by dcfgen) boots three
// Lely BasicSlaves (nodes 2, 3, 4) on Lely's userspace virtual CAN bus. What
// differs is each slave's EDS (this folder, written by make_comm_eds.py: SYNC
// producer or consumer, an RPDO with a deadline, a synchronous TPDO or RPDO) and
// the scenario (kScenarios).
//
// The ground truth is written to stderr, one line per event, in the format of
// the CANopenNode hub's .events files (samples/canopennode/README.md):
//   # SECONDS DEVICE: TEXT
// SECONDS on the log's clock (CLOCK_MONOTONIC, program start = 1700000000 s),
// DEVICE one of master, s2, s3, s4. A slave prints its own NMT state after
// every change (Lely calls OnCommand after the transition, for a command from
// the bus and for the one its 1029h handling gives itself), every EMCY it
// sends (from the callback in which Lely raised it, with the code and error
// register Lely put on its error stack, co_emcy_peek()), every RPDO error
// (OnRpdoError) and SYNC length error (OnSyncError), heartbeat and life
// guarding events, the first RPDO and SYNC after a pause and near the end a
// status line: state, error register 1001h, the top of its EMCY error stack
// and its SYNC/RPDO counts. The master prints its commands, heartbeat events,
// the slaves' states it sees, boot results and the EMCYs it receives.
//
// Usage: record_comm SCENARIO OUT.log 2> OUT.events
// Run it in samples/lely/ (the master loads master.dcf and the slaveN.bin its
// 1F22h names from the working directory; the slaves' EDS are comm/*.eds).
//
// Part of nmtcheck (MIT, see pyproject.toml). It contains no Lely code; it
// only includes the headers of, and links against, an installed lely-core
// (Apache-2.0).

#include "../recorder.hpp"

#include <lely/co/dev.hpp>
#include <lely/co/emcy.hpp>
#include <lely/co/nmt.hpp>
#include <lely/util/diag.h>

namespace {

double
abs_now() {
  return kEpoch + rel_now();
}

void
log_event(const char* dev, const char* fmt, ...)
    __attribute__((format(printf, 2, 3)));

void
log_event(const char* dev, const char* fmt, ...) {
  std::fprintf(stderr, "# %.6f %s: ", abs_now(), dev);
  va_list ap;
  va_start(ap, fmt);
  std::vfprintf(stderr, fmt, ap);
  va_end(ap);
  std::fputc('\n', stderr);
}

// Lely's own diagnostics: warnings and errors only, as "# lely: ..." lines
// (its debug and info messages would drown the events).
void
lely_diag(void*, enum diag_severity severity, int, const char* format,
          va_list ap) {
  if (severity < DIAG_WARNING) return;
  std::fputs("# lely: ", stderr);
  std::vfprintf(stderr, format, ap);
  std::fputc('\n', stderr);
}

void
lely_diag_at(void* handle, enum diag_severity severity, int errc,
             const struct floc*, const char* format, va_list ap) {
  lely_diag(handle, severity, errc, format, ap);
}

const char*
st_name_u8(uint8_t st) {
  switch (st & ~CO_NMT_ST_TOGGLE) {
    case CO_NMT_ST_BOOTUP:
      return "INITIALIZING";
    case CO_NMT_ST_STOP:
      return "STOPPED";
    case CO_NMT_ST_START:
      return "OPERATIONAL";
    case CO_NMT_ST_RESET_NODE:
      return "RESET_NODE";
    case CO_NMT_ST_RESET_COMM:
      return "RESET_COMM";
    case CO_NMT_ST_PREOP:
      return "PRE-OPERATIONAL";
    default:
      return "?";
  }
}

class CommMaster : public canopen::BasicMaster {
 public:
  using BasicMaster::BasicMaster;

 private:
  void
  OnCommand(NmtCommand cs) noexcept override {
    log_event("master", "own NMT state change by command %s", cs_name(cs));
    BasicMaster::OnCommand(cs);
  }
  void
  OnHeartbeat(uint8_t id, bool occurred) noexcept override {
    log_event("master", "heartbeat event for node %d %s", id,
              occurred ? "occurred (timeout)" : "resolved");
    BasicMaster::OnHeartbeat(id, occurred);
  }
  void
  OnState(uint8_t id, NmtState st) noexcept override {
    log_event("master", "node %d state %s", id, st_name(st));
    BasicMaster::OnState(id, st);
  }
  void
  OnNodeGuarding(uint8_t id, bool occurred) noexcept override {
    log_event("master", "node guarding event for node %d %s", id,
              occurred ? "occurred (timeout)" : "resolved");
    BasicMaster::OnNodeGuarding(id, occurred);
  }
  void
  OnBoot(uint8_t id, NmtState st, char es,
         const std::string& what) noexcept override {
    log_event("master",
              "boot-slave process for node %d finished: state %s, error "
              "status '%c' %s",
              id, st_name(st), es ? es : '0', what.c_str());
    BasicMaster::OnBoot(id, st, es, what);
  }
  void
  OnEmcy(uint8_t id, uint16_t eec, uint8_t er, uint8_t msef[5]) noexcept
      override {
    log_event("master", "EMCY received from node %d: code %04X register %02X",
              id, eec, er);
    BasicMaster::OnEmcy(id, eec, er, msef);
  }
};

class CommSlave : public canopen::BasicSlave {
 public:
  CommSlave(ev_exec_t* exec, io::TimerBase& timer, io::CanChannelBase& chan,
            const std::string& eds, int node)
      : BasicSlave(exec, timer, chan, eds, "", node), node_(node) {
    std::snprintf(dev_, sizeof(dev_), "s%d", node);
  }

  // Application: count and send TPDO1 (2000h:00), as ../recorder.hpp's Slave.
  void
  Tick() {
    uint32_t v = (*this)[0x2000][0];
    (*this)[0x2000][0] = v + 1;
    (*this)[0x2000][0].SetEvent();
  }

  void
  Status() {
    co_dev_t* dev = co_nmt_get_dev(c_nmt());
    uint16_t eec = 0;
    uint8_t er = 0;
    co_emcy_t* emcy = co_nmt_get_emcy(c_nmt());
    if (emcy) co_emcy_peek(emcy, &eec, &er);
    log_event(dev_,
              "status: NMT state %s, error register %02X, EMCY error stack top "
              "%04X, SYNC %lu, RPDO %lu",
              st_name_u8(co_nmt_get_st(c_nmt())),
              co_dev_get_val_u8(dev, 0x1001, 0x00), eec, syncs_, rpdos_);
  }

 private:
  // The NMT service as the C API of <lely/co/nmt.h> names it.
  co_nmt_t*
  c_nmt() const {
    return reinterpret_cast<co_nmt_t*>(nmt());
  }

  // Lely has just pushed an EMCY onto its error stack and sent it (1015h = 0:
  // no inhibit time): print what is on top of the stack.
  void
  EmcySent(const char* why) {
    co_emcy_t* emcy = co_nmt_get_emcy(c_nmt());
    if (!emcy) return;
    uint16_t eec = 0;
    uint8_t er = 0;
    co_emcy_peek(emcy, &eec, &er);
    log_event(dev_, "EMCY sent: code %04X register %02X (%s)",
              eec, er, why);
  }

  void
  OnCommand(NmtCommand cs) noexcept override {
    log_event(dev_, "NMT state %s (Lely OnCommand %s)",
              st_name_u8(co_nmt_get_st(c_nmt())), cs_name(cs));
  }
  void
  OnHeartbeat(uint8_t id, bool occurred) noexcept override {
    log_event(dev_, "heartbeat event for node %d %s", id,
              occurred ? "occurred (timeout)" : "resolved");
    if (occurred) EmcySent("heartbeat consumer timeout");
  }
  void
  OnLifeGuarding(bool occurred) noexcept override {
    log_event(dev_, "life guarding event %s",
              occurred ? "occurred (timeout)" : "resolved");
    if (occurred) EmcySent("life guarding timeout");
  }
  void
  OnRpdoError(int num, uint16_t eec, uint8_t er) noexcept override {
    log_event(dev_, "RPDO %d error: code %04X register %02X (Lely OnRpdoError)",
              num, eec, er);
    Error(eec, er);  // what Lely's default OnRpdoError() does: the EMCY
    EmcySent("RPDO error");
  }
  void
  OnSyncError(uint16_t eec, uint8_t er) noexcept override {
    log_event(dev_, "SYNC error: code %04X register %02X (Lely OnSyncError)",
              eec, er);
    Error(eec, er);  // what Lely's default OnSyncError() does
    EmcySent("SYNC error");
  }
  void
  OnRpdo(int num, ::std::error_code ec, const void*, ::std::size_t n) noexcept
      override {
    double now = rel_now();
    if (!rpdos_ || now - last_rpdo_ > 0.6)
      log_event(dev_, "RPDO %d received (%zu bytes, %s)%s", num, n,
                ec ? ec.message().c_str() : "ok",
                rpdos_ ? " after a pause" : ", the first");
    ++rpdos_;
    last_rpdo_ = now;
  }
  void
  OnSync(uint8_t cnt, const time_point&) noexcept override {
    double now = rel_now();
    if (!syncs_ || now - last_sync_ > 0.075)
      log_event(dev_, "SYNC %s counter %u%s", node_ == sync_producer ? "sent" : "received",
                cnt, syncs_ ? " after a pause" : ", the first");
    ++syncs_;
    last_sync_ = now;
  }

 public:
  static int sync_producer;

 private:
  int node_;
  char dev_[8];
  unsigned long syncs_{0};
  unsigned long rpdos_{0};
  double last_sync_{0};
  double last_rpdo_{0};
};

int CommSlave::sync_producer = 0;

// A channel on the main bus that stands in for a faulty application on another
// device: it writes the frames a scenario asks for (the only frames of these
// logs that Lely did not send) and reads and drops the rest.
class Tool {
 public:
  Tool(io::Context& ctx, ev_exec_t* exec, io::VirtualCanController& bus)
      : chan_(ctx, exec),
        read_(&msg_, nullptr, nullptr, exec,
              [this](int r, std::error_code ec) {
                if (r != -1 || ec != std::errc::operation_canceled)
                  chan_.submit_read(read_);
              }) {
    chan_.open(bus);
    chan_.submit_read(read_);
  }

  void
  Write(const can_msg& msg) {
    std::error_code ec;
    chan_.write(msg, 0, ec);
    if (ec) {
      ++errors;
      std::fprintf(stderr, "tool: write failed: %s\n", ec.message().c_str());
    } else {
      ++sent;
    }
  }

  uint64_t sent{0};
  uint64_t errors{0};

 private:
  io::VirtualCanChannel chan_;
  can_msg msg_ = CAN_MSG_INIT;
  io::CanChannelRead read_;
};

struct Scenario {
  const char* name;
  const char* what;
  const char* eds[3];  // nodes 2, 3, 4
  int sync_producer;
};

const Scenario kScenarios[] = {
    {"rpdo_producer_stopped",
     "node 3's RPDO1 (node 2's TPDO1, 182h) has a 750 ms deadline; the master "
     "stops node 2 at 4 s and starts it at 6 s; run to 9 s",
     {"slave.eds", "comm/rpdo_deadline.eds", "slave.eds"}, 0},
    {"sync_producer_stopped",
     "node 4 produces SYNC every 50 ms, nodes 2, 3 consume it (1006h = 50 ms); "
     "the master stops node 4 at 4 s and starts it at 6 s; run to 9 s",
     {"comm/sync_consumer.eds", "comm/sync_consumer.eds", "comm/sync_producer.eds"}, 4},
    {"master_unplugged",
     "the master (heartbeat producer for nodes 2, 3 and guarding node 4) is "
     "unplugged at 4 s for good; run to 7 s",
     {"slave.eds", "slave.eds", "slave.eds"}, 0},
    {"sync_pdo",
     "node 4 produces SYNC every 50 ms, node 2's TPDO1 is synchronous (every "
     "SYNC) and node 3's RPDO1; nothing goes wrong; run to 6 s",
     {"comm/sync_tpdo.eds", "comm/sync_rpdo.eds", "comm/sync_producer.eds"}, 4},
    {"sync_length",
     "node 4 produces SYNC without a counter (DLC 0) every 50 ms, nodes 2, 3 "
     "consume it; at 4 s another device's application (the recorder's tool "
     "channel) sends one SYNC with DLC 1 (080#05); run to 6 s",
     {"comm/sync_consumer.eds", "comm/sync_consumer.eds", "comm/sync_producer.eds"}, 4},
};

void
usage(const char* argv0) {
  std::fprintf(stderr, "usage: %s SCENARIO OUT.log\nscenarios:\n", argv0);
  for (const auto& s : kScenarios)
    std::fprintf(stderr, "  %-24s %s\n", s.name, s.what);
}

}  // namespace

int
main(int argc, char* argv[]) {
  if (argc != 3) {
    usage(argv[0]);
    return 2;
  }
  const Scenario* sc = nullptr;
  for (const auto& s : kScenarios)
    if (std::string(argv[1]) == s.name) sc = &s;
  if (!sc) {
    usage(argv[0]);
    return 2;
  }
  const std::string scenario = sc->name;
  CommSlave::sync_producer = sc->sync_producer;

  FILE* out = std::fopen(argv[2], "w");
  if (!out) {
    std::perror(argv[2]);
    return 2;
  }

  io::IoGuard io_guard;
  io::Context ctx;
  io::Poll poll(ctx);
  ev::Loop loop(poll.get_poll());
  ev_exec_t* exec = loop.get_executor();

  diag_set_handler(&lely_diag, nullptr);
  diag_at_set_handler(&lely_diag_at, nullptr);
  g_start = mono_now();
  std::fprintf(stderr, "# recorder start %.6f scenario %s\n", kEpoch,
               scenario.c_str());

  io::VirtualCanController bus(io::clock_monotonic);
  Recorder recorder(ctx, exec, bus, out, "vcan0");

  std::map<int, std::unique_ptr<Connector>> conn;
  for (int id : {1, 2, 3, 4})
    conn[id] = std::make_unique<Connector>(ctx, exec, bus, id);
  // Only where a scenario needs it, so the others run without the extra channel.
  std::unique_ptr<Tool> tool;
  if (scenario == "sync_length") tool = std::make_unique<Tool>(ctx, exec, bus);

  std::map<int, std::unique_ptr<io::Timer>> dev_timer;
  std::map<int, std::unique_ptr<CommSlave>> slaves;
  std::unique_ptr<CommMaster> master;

  std::vector<std::unique_ptr<io::Timer>> timers;
  auto at = [&](double t, std::function<void()> f) {
    auto tm = std::make_unique<io::Timer>(poll, exec, CLOCK_MONOTONIC);
    auto when = g_start + std::chrono::duration_cast<std::chrono::nanoseconds>(
                              std::chrono::duration<double>(t));
    tm->settime(io::Timer::time_point(when));
    tm->submit_wait(exec, [f](int, std::error_code ec) {
      if (!ec) f();
    });
    timers.push_back(std::move(tm));
  };

  // The same power-on order as ../record.cpp: master, then nodes 2, 3, 4.
  at(0.0, [&] {
    log_event("master", "power on (master.dcf, master.bin)");
    dev_timer[1] = std::make_unique<io::Timer>(poll, exec, CLOCK_MONOTONIC);
    master = std::make_unique<CommMaster>(exec, *dev_timer[1], conn[1]->dev,
                                          "master.dcf", "master.bin", 1);
    master->Reset();
    for (int id : {2, 3, 4}) {
      char dev[8];
      std::snprintf(dev, sizeof(dev), "s%d", id);
      log_event(dev, "power on (%s)", sc->eds[id - 2]);
      dev_timer[id] = std::make_unique<io::Timer>(poll, exec, CLOCK_MONOTONIC);
      slaves[id] = std::make_unique<CommSlave>(exec, *dev_timer[id],
                                               conn[id]->dev, sc->eds[id - 2], id);
      slaves[id]->Reset();
    }
  });

  // The slaves' application: every 500 ms bump the counter (TPDO1), off the
  // whole-second grid of the scenario actions.
  io::Timer app_timer(poll, exec, CLOCK_MONOTONIC);
  std::function<void(int, std::error_code)> app_tick;
  app_tick = [&](int, std::error_code ec) {
    if (ec) return;
    for (auto& kv : slaves) kv.second->Tick();
    app_timer.submit_wait(exec, app_tick);
  };
  app_timer.settime(io::Timer::time_point(g_start + 370ms), 500ms);
  app_timer.submit_wait(exec, app_tick);

  auto command = [&](NmtCommand cs, int id) {
    log_event("master", "application: NMT %s node %d", cs_name(cs), id);
    master->Command(cs, id);
  };

  double end = 9.0;
  if (scenario == "rpdo_producer_stopped") {
    at(4.0, [&] { command(NmtCommand::STOP, 2); });
    at(6.0, [&] { command(NmtCommand::START, 2); });
  } else if (scenario == "sync_producer_stopped") {
    at(4.0, [&] { command(NmtCommand::STOP, 4); });
    at(6.0, [&] { command(NmtCommand::START, 4); });
  } else if (scenario == "master_unplugged") {
    at(4.0, [&] {
      log_event("master", "unplugged (for good)");
      conn[1]->set_plugged(false);
    });
    end = 7.0;
  } else if (scenario == "sync_pdo") {
    end = 6.0;
  } else if (scenario == "sync_length") {
    at(4.0, [&] {
      can_msg msg = CAN_MSG_INIT;
      msg.id = 0x80;
      msg.len = 1;
      msg.data[0] = 0x05;
      log_event("tool", "writes SYNC 080#05 (DLC 1): a faulty application");
      tool->Write(msg);
    });
    end = 6.0;
  }

  at(end - 0.15, [&] {
    for (auto& kv : slaves) kv.second->Status();
  });
  at(end, [&] {
    for (auto& kv : conn) kv.second->set_plugged(false);
  });
  at(end + 0.2, [&] { loop.stop(); });

  loop.run();
  std::fflush(out);

  uint64_t sent = tool ? tool->sent : 0;
  int rc = tool && tool->errors ? 1 : 0;
  if (tool) std::fprintf(stderr, "# tool: sent %" PRIu64 "\n", tool->sent);
  for (auto& kv : conn) {
    const Connector& c = *kv.second;
    sent += c.sent;
    std::fprintf(stderr,
                 "# node %d: sent %" PRIu64 " (dropped while unplugged %" PRIu64
                 "), received %" PRIu64 " (delivered %" PRIu64 "), errors %" PRIu64
                 "\n",
                 kv.first, c.sent, c.sent_lost, c.received, c.delivered,
                 c.errors);
    if (c.errors) rc = 1;
  }
  for (auto& kv : conn) {
    const Connector& c = *kv.second;
    if (c.received + c.sent != recorder.frames()) {
      std::fprintf(stderr, "# MISMATCH: node %d received+sent != logged\n",
                   kv.first);
      rc = 1;
    }
  }
  std::fprintf(stderr, "# logged %" PRIu64 " frames, sent %" PRIu64 " -> %s\n",
               recorder.frames(), sent,
               sent == recorder.frames() && !rc ? "OK" : "MISMATCH");
  if (sent != recorder.frames()) rc = 1;

  std::fclose(out);
  std::fflush(stderr);
  std::_Exit(rc);
}
