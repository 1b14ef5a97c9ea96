// record_boot.cpp - record CiA 302-2 boot-slave failures of the Lely CANopen master,
// with the master's own verdict beside the frames.
//
// The same bus, devices and checks as ../record.cpp (one Lely BasicMaster, node-ID 1,
// and Lely BasicSlaves on Lely's userspace virtual CAN bus; every frame logged exactly
// once as a candump -L line, time-stamped by the bus controller's CLOCK_MONOTONIC,
// shifted so the program start is 1700000000 s). What differs: the slaves (node-IDs,
// the EDS each powers on with, when it powers on, an application that ignores 1017h)
// come from the scenario table below, the master's files from the scenario's folder,
// and every call of the master's OnBoot(id, state, es, what) is written, on the same
// clock as the frames, to OUT.onboot.jsonl: one JSON object per line,
//   {"time": 1700000000.123456, "node": 2, "state": "PRE-OPERATIONAL", "es": "C",
//    "what": "Value of object 1000 ..."}
// ("es" is "" when the boot succeeded). That is Lely's own letter, for the tests to
// compare nmtcheck's reconstruction with.
//
// Usage: record_boot SCENARIO OUT.log   (run in samples/lely/boot; without arguments
//        it lists the scenarios). Events are printed on stderr as in ../record.cpp.
//
// Part of nmtcheck (MIT, see pyproject.toml). It contains no Lely code; it only
// includes the headers of, and links against, an installed lely-core (Apache-2.0).

#include "../recorder.hpp"

namespace {

FILE* g_onboot = nullptr;  // OUT.onboot.jsonl

class Master : public canopen::BasicMaster {
 public:
  using BasicMaster::BasicMaster;

 private:
  void
  OnCommand(NmtCommand cs) noexcept override {
    event("master: own NMT state change by command %s", cs_name(cs));
    BasicMaster::OnCommand(cs);
  }
  void
  OnHeartbeat(uint8_t id, bool occurred) noexcept override {
    event("master: heartbeat event for node %d %s", id,
          occurred ? "occurred (timeout)" : "resolved");
    BasicMaster::OnHeartbeat(id, occurred);
  }
  void
  OnState(uint8_t id, NmtState st) noexcept override {
    event("master: node %d state %s", id, st_name(st));
    BasicMaster::OnState(id, st);
  }
  void
  OnNodeGuarding(uint8_t id, bool occurred) noexcept override {
    event("master: node guarding event for node %d %s", id,
          occurred ? "occurred (timeout)" : "resolved");
    BasicMaster::OnNodeGuarding(id, occurred);
  }
  void
  OnBoot(uint8_t id, NmtState st, char es,
         const std::string& what) noexcept override {
    if (g_onboot) {
      std::fprintf(g_onboot,
                   "{\"time\": %.6f, \"node\": %d, \"state\": \"%s\", "
                   "\"es\": \"%s\", \"what\": \"%s\"}\n",
                   kEpoch + rel_now(), id, st_name(st),
                   es ? std::string(1, es).c_str() : "", what.c_str());
      std::fflush(g_onboot);
    }
    event("master: boot-slave process for node %d finished: state %s, "
          "error status '%c' %s",
          id, st_name(st), es ? es : '0', what.c_str());
    BasicMaster::OnBoot(id, st, es, what);
  }
  void
  OnEmcy(uint8_t id, uint16_t eec, uint8_t er, uint8_t msef[5]) noexcept
      override {
    event("master: EMCY from node %d: %04X %02X", id, eec, er);
    BasicMaster::OnEmcy(id, eec, er, msef);
  }
};

// One slave of a scenario: its node-ID, the EDS it powers on with (relative to
// samples/lely/boot), when it powers on (s), and whether its application ignores
// writes of 1017h.
struct SlaveSpec {
  int id;
  const char* eds;
  double power_on;
  bool ignore_1017;
};

struct Scenario {
  const char* name;
  const char* dir;  // the master's master.dcf / master.bin (dcfgen output)
  double end;
  std::vector<SlaveSpec> slaves;
  const char* what;
};

const std::vector<Scenario> kScenarios = {
    {"identity", "identity/", 6.0,
     {{2, "slave_id.eds", 0, false},
      {3, "slave_id.eds", 0, false},
      {4, "slave_id.eds", 0, false},
      {5, "slave_id.eds", 0, false},
      {6, "slave_id.eds", 0, false},
      {7, "slave_id.eds", 0, false}},
     "identity/master.dcf expects another device type (node 2), vendor-ID (3), "
     "product code (4), revision (5), serial number (6) than the slaves have; "
     "node 7 matches"},
    {"sequence", "sequence/", 10.0,
     {{2, "slave_ro1017.eds", 0, false},
      {3, "../slave.eds", 0, true},
      {4, "slave_nosdo.eds", 0, false},
      {5, "../slave.eds", 1.5, false}},
     "node 2 refuses the 1017h download, node 3 never produces a heartbeat, "
     "node 4 (mandatory) has no SDO server, node 5 (mandatory) powers on at "
     "1.5 s"},
    {"keepalive", "keepalive/", 6.0,
     {{2, "../slave.eds", 0, false},
      {3, "../slave.eds", 0, false},
      {4, "slave_op.eds", 0, false},
      {5, "slave_op.eds", 0, false}},
     "keep-alive node 2 is silent, keep-alive node 3 does not answer the "
     "guarding RTR, keep-alive node 4 is OPERATIONAL, node 5 starts itself "
     "after its reset"},
};

void
usage(const char* argv0) {
  std::fprintf(stderr, "usage: %s SCENARIO OUT.log\nscenarios:\n", argv0);
  for (const auto& s : kScenarios)
    std::fprintf(stderr, "  %-10s %s\n", s.name, s.what);
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
    if (argv[1] == std::string(s.name)) sc = &s;
  if (!sc) {
    usage(argv[0]);
    return 2;
  }
  const std::string dir = sc->dir;

  FILE* out = std::fopen(argv[2], "w");
  if (!out) {
    std::perror(argv[2]);
    return 2;
  }
  std::string side = argv[2];
  if (side.size() > 4 && side.compare(side.size() - 4, 4, ".log") == 0)
    side.resize(side.size() - 4);
  side += ".onboot.jsonl";
  g_onboot = std::fopen(side.c_str(), "w");
  if (!g_onboot) {
    std::perror(side.c_str());
    return 2;
  }

  io::IoGuard io_guard;
  io::Context ctx;
  io::Poll poll(ctx);
  ev::Loop loop(poll.get_poll());
  ev_exec_t* exec = loop.get_executor();

  g_start = mono_now();

  io::VirtualCanController bus(io::clock_monotonic);
  Recorder recorder(ctx, exec, bus, out, "vcan0");

  std::map<int, std::unique_ptr<Connector>> conn;
  conn[1] = std::make_unique<Connector>(ctx, exec, bus, 1);
  for (const auto& s : sc->slaves) {
    conn[s.id] = std::make_unique<Connector>(ctx, exec, bus, s.id);
    // A slave that powers on later is off the bus until then: its channel must
    // not queue the frames sent before (it would answer them all at power-on).
    if (s.power_on > 0) conn[s.id]->set_plugged(false);
  }

  std::map<int, std::unique_ptr<io::Timer>> dev_timer;
  std::map<int, std::unique_ptr<Slave>> slaves;
  std::unique_ptr<Master> master;

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

  auto power_on_slave = [&](const SlaveSpec& s) {
    event("node %d: power on (%s)", s.id, s.eds);
    conn[s.id]->set_plugged(true);
    dev_timer[s.id] = std::make_unique<io::Timer>(poll, exec, CLOCK_MONOTONIC);
    slaves[s.id] = std::make_unique<Slave>(exec, *dev_timer[s.id],
                                           conn[s.id]->dev, s.eds, s.id);
    if (s.ignore_1017) slaves[s.id]->IgnoreHeartbeatWrites();
    slaves[s.id]->Reset();
  };

  // The slaves' application: every 500 ms bump the counter (TPDO1).
  io::Timer app_timer(poll, exec, CLOCK_MONOTONIC);
  std::function<void(int, std::error_code)> app_tick;
  app_tick = [&](int, std::error_code ec) {
    if (ec) return;
    for (auto& kv : slaves) kv.second->Tick();
    app_timer.submit_wait(exec, app_tick);
  };
  app_timer.settime(io::Timer::time_point(g_start + 370ms), 500ms);
  app_timer.submit_wait(exec, app_tick);

  at(0.0, [&] {
    event("master: power on");
    dev_timer[1] = std::make_unique<io::Timer>(poll, exec, CLOCK_MONOTONIC);
    master = std::make_unique<Master>(exec, *dev_timer[1], conn[1]->dev,
                                      dir + "master.dcf", dir + "master.bin",
                                      1);
    master->Reset();
    for (const auto& s : sc->slaves)
      if (s.power_on == 0) power_on_slave(s);
  });
  for (const auto& s : sc->slaves)
    if (s.power_on > 0) at(s.power_on, [&, s] { power_on_slave(s); });

  at(sc->end, [&] {
    for (auto& kv : conn) kv.second->set_plugged(false);
  });
  at(sc->end + 0.2, [&] { loop.stop(); });

  loop.run();
  std::fflush(out);

  uint64_t sent = 0;
  int rc = 0;
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
  std::fclose(g_onboot);
  std::fflush(stderr);
  std::_Exit(rc);
}
