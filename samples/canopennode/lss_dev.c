/*
 * One CANopenNode v4 device with LSS (CiA 305) on the hub bus of hub.py: an LSS slave, or
 * an LSS master that runs a script of CANopenNode LSS master calls. Written for
 * nmtcheck's LSS recordings (samples/canopennode/lss/, see README.md there); links
 * against an unmodified CANopenNode source tree (CANopen.c, 301/, 305/) plus our OD.c and
 * CO_driver.c, built with -DNMTCHECK_LSS (CO_driver_target.h then enables the LSS slave,
 * its direct fastscan answer, and the LSS master).
 *
 * Main loop as CANopenNode's example/main_blank.c: at every communication reset
 * CO_LSSinit() with the slave's identity and its pending node-ID, then CO_CANopenInit()
 * with that node-ID (255: non-configured, only LSS runs); CO_process() at least every
 * 1 ms and right after each received frame.
 *
 * usage: lss_dev --hub DIR --name NAME --node N|255 [--identity V:P:R:S (hex)]
 *                [--hb MS] [--store] [--bitrate] [--master --script "CMD;CMD;..."]
 *   --store     the slave has a store callback (CO_LSSslave_initCfgStoreCall);
 *               without it CANopenNode answers "store configuration" with 1 (not supported)
 *   --bitrate   the slave has a bit-rate check callback; without it CANopenNode stays
 *               silent on "configure bit timing" and "activate bit timing"
 *   --master    LSS master; the script's commands run one after the other, each to its
 *               end (the CANopenNode call returns something other than WAIT_SLAVE):
 *     wait MS | timeout MS | select V:P:R:S | select_all | deselect | inquire_node |
 *     inquire_vendor | node N | store | bitrate KBIT | activate MS | fastscan | nmt CS NODE
 * Ground truth, printed to stderr (the hub's .events file) with CLOCK_REALTIME stamps:
 * every master call and its CANopenNode return code (and what it returned: node-ID,
 * vendor-ID, the identity a fastscan found), every NMT state change of each device,
 * each slave's communication reset with the node-ID it starts with, and what its store
 * callback stored.
 */
#include <errno.h>
#include <poll.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <time.h>
#include <unistd.h>

#include "CANopen.h"
#include "OD.h"

#define FIRST_HB_TIME        500
#define SDO_SRV_TIMEOUT_TIME 1000
#define SDO_CLI_TIMEOUT_TIME 500

static CO_t* CO = NULL;
static int hubFd = -1;
static const char* devName = "dev";
static int nodeId = 0;
static int hbPowerOn = 1000;
static int hasStore = 0, hasBitrate = 0, isMaster = 0;
static uint32_t identity[4] = {0, 0, 0, 0};
static char script[2048] = "";
static uint8_t pendingNodeId = 0xFF; /* survives communication resets (RAM) */
static uint16_t pendingBitRate = 0;

static uint64_t
now_us(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000000u + (uint64_t)ts.tv_nsec / 1000u;
}

static void
logf_(const char* fmt, ...) {
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    char line[512];
    int n = snprintf(line, sizeof(line), "# %ld.%06ld %s: ", (long)ts.tv_sec, ts.tv_nsec / 1000, devName);
    va_list ap;
    va_start(ap, fmt);
    n += vsnprintf(line + n, sizeof(line) - (size_t)n - 1, fmt, ap);
    va_end(ap);
    if (n > (int)sizeof(line) - 2) {
        n = (int)sizeof(line) - 2;
    }
    line[n++] = '\n';
    (void)!write(2, line, (size_t)n);
}

static const char*
ret_name(CO_LSSmaster_return_t r) {
    switch (r) {
        case CO_LSSmaster_SCAN_FINISHED: return "SCAN_FINISHED";
        case CO_LSSmaster_WAIT_SLAVE: return "WAIT_SLAVE";
        case CO_LSSmaster_OK: return "OK";
        case CO_LSSmaster_TIMEOUT: return "TIMEOUT";
        case CO_LSSmaster_ILLEGAL_ARGUMENT: return "ILLEGAL_ARGUMENT";
        case CO_LSSmaster_INVALID_STATE: return "INVALID_STATE";
        case CO_LSSmaster_SCAN_NOACK: return "SCAN_NOACK";
        case CO_LSSmaster_SCAN_FAILED: return "SCAN_FAILED";
        case CO_LSSmaster_OK_ILLEGAL_ARGUMENT: return "OK_ILLEGAL_ARGUMENT";
        case CO_LSSmaster_OK_MANUFACTURER: return "OK_MANUFACTURER";
        default: return "?";
    }
}

static void
on_nmt_changed(CO_NMT_internalState_t state) {
    logf_("NMT state %d", (int)state);
}

static bool_t
on_store(void* object, uint8_t id, uint16_t bitRate) {
    (void)object;
    logf_("LSS store callback: node-ID %u, bit rate %u stored", id, bitRate);
    return true;
}

static bool_t
on_check_bitrate(void* object, uint16_t bitRate) {
    (void)object;
    logf_("LSS bit-rate check callback: %u kbit/s supported", bitRate);
    return true;
}

static void
on_activate_bitrate(void* object, uint16_t delay) {
    (void)object;
    logf_("LSS activate bit timing callback: switch delay %u ms (the hub bus has no bit rate)", delay);
}

/* ------------------------------------------------------------ master script */
static char* cmdNext = NULL; /* the rest of the script */
static char cmd[128] = "";
static int cmdActive = 0;
static uint64_t waitUntil = 0;
static CO_LSSmaster_fastscan_t fastscan;

static int
next_command(void) {
    while (cmdNext != NULL && *cmdNext) {
        char* end = strchr(cmdNext, ';');
        size_t len = end ? (size_t)(end - cmdNext) : strlen(cmdNext);
        if (len >= sizeof(cmd)) {
            len = sizeof(cmd) - 1;
        }
        memcpy(cmd, cmdNext, len);
        cmd[len] = 0;
        cmdNext = end ? end + 1 : cmdNext + strlen(cmdNext);
        if (cmd[0]) {
            return 1;
        }
    }
    return 0;
}

static int
parse_identity(const char* v, CO_LSS_address_t* a) {
    unsigned x[4];
    if (sscanf(v, "%x:%x:%x:%x", &x[0], &x[1], &x[2], &x[3]) != 4) {
        return 0;
    }
    a->identity.vendorID = x[0];
    a->identity.productCode = x[1];
    a->identity.revisionNumber = x[2];
    a->identity.serialNumber = x[3];
    return 1;
}

/* one step of the current command; 1 while it waits for the slave */
static int
master_step(uint32_t diff) {
    CO_LSSmaster_t* m = CO->LSSmaster;
    char word[32] = "", arg[64] = "";
    sscanf(cmd, "%31s %63[^\n]", word, arg);
    uint32_t d = cmdActive ? diff : 0;
    CO_LSSmaster_return_t r = CO_LSSmaster_OK;
    uint32_t value = 0;
    if (!strcmp(word, "wait")) {
        if (!cmdActive) {
            waitUntil = now_us() + (uint64_t)atoi(arg) * 1000u;
        }
        return now_us() < waitUntil;
    } else if (!strcmp(word, "timeout")) {
        CO_LSSmaster_changeTimeout(m, (uint16_t)atoi(arg));
        logf_("master: CO_LSSmaster_changeTimeout(%s ms)", arg);
        return 0;
    } else if (!strcmp(word, "select")) {
        CO_LSS_address_t a;
        parse_identity(arg, &a);
        r = CO_LSSmaster_swStateSelect(m, d, &a);
    } else if (!strcmp(word, "select_all")) {
        r = CO_LSSmaster_swStateSelect(m, d, NULL);
    } else if (!strcmp(word, "deselect")) {
        r = CO_LSSmaster_swStateDeselect(m);
    } else if (!strcmp(word, "inquire_node")) {
        r = CO_LSSmaster_Inquire(m, d, CO_LSS_INQUIRE_NODE_ID, &value);
    } else if (!strcmp(word, "inquire_vendor")) {
        r = CO_LSSmaster_Inquire(m, d, CO_LSS_INQUIRE_VENDOR, &value);
    } else if (!strcmp(word, "node")) {
        r = CO_LSSmaster_configureNodeId(m, d, (uint8_t)atoi(arg));
    } else if (!strcmp(word, "store")) {
        r = CO_LSSmaster_configureStore(m, d);
    } else if (!strcmp(word, "bitrate")) {
        r = CO_LSSmaster_configureBitTiming(m, d, (uint16_t)atoi(arg));
    } else if (!strcmp(word, "activate")) {
        r = CO_LSSmaster_ActivateBit(m, (uint16_t)atoi(arg));
    } else if (!strcmp(word, "fastscan")) {
        if (!cmdActive) {
            memset(&fastscan, 0, sizeof(fastscan));
            for (int k = 0; k < 4; k++) {
                fastscan.scan[k] = CO_LSSmaster_FS_SCAN;
            }
        }
        r = CO_LSSmaster_IdentifyFastscan(m, d, &fastscan);
    } else if (!strcmp(word, "nmt")) {
        unsigned cs = 0, node = 0;
        sscanf(arg, "%x %u", &cs, &node);
        CO_NMT_sendCommand(CO->NMT, (CO_NMT_command_t)cs, (uint8_t)node);
        logf_("master: CO_NMT_sendCommand(%02Xh, node %u)", cs, node);
        return 0;
    } else {
        logf_("master: unknown command '%s'", cmd);
        return 0;
    }
    if (r == CO_LSSmaster_WAIT_SLAVE) {
        return 1;
    }
    if (!strcmp(word, "fastscan") && r == CO_LSSmaster_SCAN_FINISHED) {
        logf_("master: %s -> %s, found %08X:%08X:%08X:%08X", cmd, ret_name(r),
              (unsigned)fastscan.found.identity.vendorID, (unsigned)fastscan.found.identity.productCode,
              (unsigned)fastscan.found.identity.revisionNumber, (unsigned)fastscan.found.identity.serialNumber);
    } else if (!strncmp(word, "inquire", 7) && r == CO_LSSmaster_OK) {
        logf_("master: %s -> %s, value %08X", cmd, ret_name(r), (unsigned)value);
    } else {
        logf_("master: %s -> %s", cmd, ret_name(r));
    }
    return 0;
}

static void
master_process(uint32_t diff) {
    for (;;) {
        if (!cmdActive) {
            if (!next_command()) {
                return;
            }
        }
        int waiting = master_step(diff);
        cmdActive = waiting;
        if (waiting) {
            return;
        }
        diff = 0;
    }
}

/* ------------------------------------------------------------------- main */
static void
receive_all(void) {
    union {
        hub_frame_t f;
        char raw[256];
    } m;
    for (;;) {
        ssize_t n = recv(hubFd, &m, sizeof(m), MSG_DONTWAIT);
        if (n < 0) {
            if (errno == EINTR) {
                continue;
            }
            return;
        }
        if (n == (ssize_t)sizeof(hub_frame_t) && m.f.type == 'F') {
            CO_CANrxFromHub(CO->CANmodule, &m.f);
        }
    }
}

int
main(int argc, char** argv) {
    const char* hubDir = NULL;
    for (int i = 1; i < argc; i++) {
        const char* o = argv[i];
        const char* v = (i + 1 < argc) ? argv[i + 1] : "";
        if (!strcmp(o, "--hub")) { hubDir = v; i++; }
        else if (!strcmp(o, "--name")) { devName = v; i++; }
        else if (!strcmp(o, "--node")) { nodeId = atoi(v); i++; }
        else if (!strcmp(o, "--hb")) { hbPowerOn = atoi(v); i++; }
        else if (!strcmp(o, "--identity")) {
            if (sscanf(v, "%x:%x:%x:%x", &identity[0], &identity[1], &identity[2], &identity[3]) != 4) {
                fprintf(stderr, "--identity V:P:R:S (hex)\n");
                return 2;
            }
            i++;
        }
        else if (!strcmp(o, "--store")) { hasStore = 1; }
        else if (!strcmp(o, "--bitrate")) { hasBitrate = 1; }
        else if (!strcmp(o, "--master")) { isMaster = 1; }
        else if (!strcmp(o, "--script")) { strncpy(script, v, sizeof(script) - 1); i++; }
        else { fprintf(stderr, "unknown option %s\n", o); return 2; }
    }
    if (hubDir == NULL || !((nodeId >= 1 && nodeId <= 127) || nodeId == 0xFF)) {
        fprintf(stderr, "usage: lss_dev --hub DIR --name NAME --node N|255 [options]\n");
        return 2;
    }
    pendingNodeId = (uint8_t)nodeId;
    cmdNext = script;

    struct sockaddr_un me = {.sun_family = AF_UNIX}, hub = {.sun_family = AF_UNIX};
    snprintf(me.sun_path, sizeof(me.sun_path), "%s/dev-%s.sock", hubDir, devName);
    snprintf(hub.sun_path, sizeof(hub.sun_path), "%s/hub.sock", hubDir);
    hubFd = socket(AF_UNIX, SOCK_DGRAM | SOCK_CLOEXEC, 0);
    unlink(me.sun_path);
    if (hubFd < 0 || bind(hubFd, (struct sockaddr*)&me, sizeof(me)) < 0
        || connect(hubFd, (struct sockaddr*)&hub, sizeof(hub)) < 0) {
        perror("hub socket");
        return 1;
    }
    hub_frame_t hello = {.type = 'H'};
    send(hubFd, &hello, sizeof(hello), 0);

    uint32_t heapMemoryUsed = 0;
    CO = CO_new(NULL, &heapMemoryUsed);
    if (CO == NULL) {
        fprintf(stderr, "CO_new failed\n");
        return 1;
    }
    OD_PERSIST_COMM.x1017_producerHeartbeatTime = (uint16_t)hbPowerOn;
    OD_PERSIST_COMM.x1018_identity.vendor_ID = identity[0];
    OD_PERSIST_COMM.x1018_identity.productCode = identity[1];
    OD_PERSIST_COMM.x1018_identity.revisionNumber = identity[2];
    OD_PERSIST_COMM.x1018_identity.serialNumber = identity[3];
    OD_PERSIST_COMM.x1800_TPDOCommunicationParameter.COB_IDUsedByTPDO |= 0x80000000u; /* no TPDO */
    uint16_t nmtControl = CO_NMT_ERR_ON_ERR_REG | CO_ERR_REG_GENERIC_ERR | CO_ERR_REG_COMMUNICATION;
    if (isMaster) {
        nmtControl |= CO_NMT_STARTUP_TO_OPERATIONAL;
    }

    CO_NMT_reset_cmd_t reset = CO_RESET_NOT;
    while (reset != CO_RESET_APP && reset != CO_RESET_QUIT) {
        CO->CANmodule->CANnormal = false;
        CO_CANsetConfigurationMode((void*)&hubFd);
        CO_CANmodule_disable(CO->CANmodule);
        if (CO_CANinit(CO, (void*)&hubFd, 0) != CO_ERROR_NO) {
            fprintf(stderr, "CO_CANinit failed\n");
            return 1;
        }
        CO_LSS_address_t lssAddress = {.identity = {.vendorID = identity[0], .productCode = identity[1],
                                                    .revisionNumber = identity[2], .serialNumber = identity[3]}};
        if (CO_LSSinit(CO, &lssAddress, &pendingNodeId, &pendingBitRate) != CO_ERROR_NO) {
            fprintf(stderr, "CO_LSSinit failed\n");
            return 1;
        }
        uint8_t activeNodeId = pendingNodeId;
        logf_("communication reset: node-ID %u%s", activeNodeId, activeNodeId == 0xFF ? " (non-configured)" : "");
        uint32_t errInfo = 0;
        CO_ReturnError_t err = CO_CANopenInit(CO, NULL, NULL, OD, NULL, nmtControl, FIRST_HB_TIME,
                                              SDO_SRV_TIMEOUT_TIME, SDO_CLI_TIMEOUT_TIME, false, activeNodeId,
                                              &errInfo);
        if (err != CO_ERROR_NO && err != CO_ERROR_NODE_ID_UNCONFIGURED_LSS) {
            fprintf(stderr, "CO_CANopenInit failed %d (OD %04X)\n", err, (unsigned)errInfo);
            return 1;
        }
        err = CO_CANopenInitPDO(CO, CO->em, OD, activeNodeId, &errInfo);
        if (err != CO_ERROR_NO && err != CO_ERROR_NODE_ID_UNCONFIGURED_LSS) {
            fprintf(stderr, "CO_CANopenInitPDO failed %d (OD %04X)\n", err, (unsigned)errInfo);
            return 1;
        }
        if (!CO->nodeIdUnconfigured) {
            CO_NMT_initCallbackChanged(CO->NMT, on_nmt_changed);
        }
        if (hasStore) {
            CO_LSSslave_initCfgStoreCall(CO->LSSslave, NULL, on_store);
        }
        if (hasBitrate) {
            CO_LSSslave_initCkBitRateCall(CO->LSSslave, NULL, on_check_bitrate);
            CO_LSSslave_initActBitRateCall(CO->LSSslave, NULL, on_activate_bitrate);
        }
        CO_CANsetNormalMode(CO->CANmodule);
        uint64_t last = now_us();
        reset = CO_RESET_NOT;
        while (reset == CO_RESET_NOT) {
            uint64_t t = now_us();
            uint64_t nextTick = last + 1000u;
            int timeout = (nextTick > t) ? (int)((nextTick - t + 999u) / 1000u) : 0;
            struct pollfd p = {.fd = hubFd, .events = POLLIN};
            poll(&p, 1, timeout);
            receive_all();
            t = now_us();
            uint32_t diff = (uint32_t)(t - last);
            last = t;
            reset = CO_process(CO, false, diff, NULL);
            if (reset != CO_RESET_NOT) {
                logf_("CO_process: %s", reset == CO_RESET_COMM ? "reset communication" : "reset node");
                break;
            }
            if (isMaster) {
                master_process(diff);
            }
        }
    }
    CO_delete(CO);
    close(hubFd);
    if (reset == CO_RESET_APP) {
        execv("/proc/self/exe", argv);
        perror("execv");
    }
    return 0;
}
