/*
 * One CANopenNode v4 device (slave or simple NMT master) on the hub bus of
 * hub.py. Written for nmtcheck's recordings (see README.md); links against an
 * unmodified CANopenNode source tree (CANopen.c and the 301 folder) plus our OD.c and
 * CO_driver.c.
 *
 * Main loop as in CANopenNode's example/main_blank.c and CANopenLinux: a
 * communication-reset loop around CO_CANinit/CO_CANopenInit/CO_CANopenInitPDO,
 * and a processing loop that calls CO_process, CO_process_SYNC,
 * CO_process_RPDO and CO_process_TPDO at least every 1 ms and right after
 * every received frame, with the measured time difference (CLOCK_MONOTONIC).
 * CO_RESET_APP (NMT reset node) re-executes the program: the device powers
 * up again with its power-on object dictionary. CO_RESET_COMM keeps the
 * object dictionary in RAM (CANopenNode behaviour).
 *
 * usage: dev --hub DIR --name NAME --node N [--hb MS] [--self-start] [--no-tpdo]
 *            [--master --slaves 2h,3h,4g [--reset-all] [--reset-delay MS] [--config-delay MS]]
 *
 *   --hb MS        power-on producer heartbeat time 1017h (default 1000)
 *   --self-start   CO_NMT_STARTUP_TO_OPERATIONAL (enter OPERATIONAL after boot-up)
 *   --no-tpdo      TPDO1 invalid at power-on
 *   --master       NMT master application (always self-starting, as
 *                  CANopenNode's example NMT_CONTROL); --slaves lists the
 *                  nodes it configures: h = heartbeat, g = node guarding
 *   --reset-all    once per program run, --reset-delay ms after the boot-up,
 *                  send NMT reset communication to all nodes (000#8200)
 *
 * Control commands from the hub (scenario driver), one text datagram each:
 *   nmt CS NODE | sdo_read NODE IDX SUB | sdo_write NODE IDX SUB LEN VALUE |
 *   emcy_set | emcy_clear | set1017 MS | config NODE | quit
 *
 * `config NODE` (master: configure and start that one
 * slave again, as at boot; for a slave that was power-cycled or reset), and
 * `--guard MS:F` (power-on 100Ch/100Dh, as stored parameters; use with --hb 0), and
 * `--sync-us US` (SYNC producer on COB-ID 80h with period US at power-on).
 *
 * SYNC and EMCY recordings (sync_emcy/ in README.md):
 *   --sync-cons-us US  power-on 1006h = US without the producer bit: a SYNC
 *                      consumer whose timeout (1.5 x 1006h) runs
 *   --sync-ovf N       power-on 1019h (synchronous counter overflow value)
 *   --emcy-inhibit N   power-on 1015h (EMCY inhibit time, 100 us units)
 *   --sync-window-us US  power-on 1007h (synchronous window length, us)
 *   control `err_set BIT CODE INFO` / `err_reset BIT INFO` (hex): the
 *   application calls CO_errorReport() / CO_errorReset(); `status` prints the
 *   NMT state, the error register 1001h and the active error bits.
 * Ground truth for the checker, printed to stderr (the hub's .events file)
 * with CLOCK_REALTIME stamps, the clock of the hub's log: every NMT state
 * change (CANopenNode's CO_NMT_initCallbackChanged callback) and every
 * EMCY the stack sends itself (CO_EM_initCallbackRx, called with ident 0
 * right after the stack's own EMCY went to CO_CANsend()).
 *
 * PDO recordings (pdo/ in README.md):
 *   --tpdo1 TYPE:INHIBIT:EVENT   power-on 1800h sub 2 (transmission type), sub 3
 *                                (inhibit time, 100 us) and sub 5 (event timer, ms)
 *   --rpdo1 COBID:TYPE:EVENT:MAP[,MAP...]  (COB-ID and mapping entries hex)
 *                                power-on 1400h sub 1, 2, 5 and 1600h (RPDO1 valid
 *                                when COB-ID bit 31 is clear); maps 2001h and/or
 *                                CANopenNode's dummy entries (index < 20h, sub 0)
 *   control `tpdo_req COUNT GAP_MS`: the application changes 2000h (+1) and asks
 *   for TPDO1 (CO_TPDOsendRequest()) COUNT times, GAP_MS ms apart; the stack
 *   sends it as its transmission type and inhibit time allow.
 * Ground truth printed with the others: the PDO configuration in force after
 * every communication reset (read back from the object dictionary, as the
 * stack initialised it), every application request, and, from the patched
 * stack of dev_inhibit (tpdo_inhibit.patch), every TPDO it sent while its
 * inhibit time was still running, from dev_late (tpdo_late.patch) every synchronous
 * TPDO it sent after the synchronous window, and from dev_emcyshort (emcy_short.patch) every
 * EMCY it sent with a DLC other than 8.
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
static int selfStart = 0, noTpdo = 0, isMaster = 0, resetAll = 0;
static int resetDelayMs = 100, configDelayMs = 50;
static unsigned guardPowerOn = 0, lifePowerOn = 0; /* power-on 100Ch/100Dh (--guard) */
static unsigned syncUs = 0; /* SYNC producer period (1006h, --sync-us), 0 = none */
static unsigned syncConsUs = 0; /* SYNC consumer period (1006h, --sync-cons-us), 0 = none */
static int syncOvf = -1;        /* power-on 1019h (--sync-ovf), -1 = OD default */
static int emcyInhibit = -1;    /* power-on 1015h (--emcy-inhibit), -1 = OD default */
static int syncWindowUs = -1;   /* power-on 1007h (--sync-window-us), -1 = OD default */
static int tpdoType = -1, tpdoInhibit = -1, tpdoEvent = -1; /* power-on 1800h:02/03/05 (--tpdo1) */
static int rpdoSet = 0;             /* --rpdo1 given */
static uint32_t rpdoCob = 0;        /* power-on 1400h:01 */
static unsigned rpdoType = 0xFE, rpdoEvent = 0; /* power-on 1400h:02/05 */
static uint32_t rpdoMap[8];         /* power-on 1600h:01.. */
static unsigned rpdoMapCount = 0;   /* power-on 1600h:00 */
static unsigned tpdoReqLeft = 0, tpdoReqGapMs = 0, tpdoReqNo = 0; /* control tpdo_req */
static uint64_t tpdoReqNext = 0;
static char slavesSpec[128] = "";
static int resetAllDone = 0; /* survives communication resets (RAM) */

static uint64_t
now_us(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000000u + (uint64_t)ts.tv_nsec / 1000u;
}

/* one line to stderr, written at once (the devices share the hub's .events file) */
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

/* ---------------------------------------------------------------- jobs */
typedef enum { J_SDO_W, J_SDO_R, J_NMT, J_LOCAL_1016, J_GUARD } jobType_t;
typedef struct {
    jobType_t type;
    uint8_t node;
    uint16_t index;
    uint8_t sub;
    uint8_t len;
    uint32_t value;
} job_t;

#define MAXJOBS 64
static job_t jobs[MAXJOBS];
static int jobHead = 0, jobTail = 0;
static int jobActive = 0; /* SDO transfer in progress */

static void
job_add(jobType_t t, int node, int index, int sub, int len, uint32_t value) {
    if ((jobTail + 1) % MAXJOBS == jobHead) {
        logf_("job queue full");
        return;
    }
    job_t* j = &jobs[jobTail];
    j->type = t;
    j->node = (uint8_t)node;
    j->index = (uint16_t)index;
    j->sub = (uint8_t)sub;
    j->len = (uint8_t)len;
    j->value = value;
    jobTail = (jobTail + 1) % MAXJOBS;
}

static void
jobs_clear(void) {
    jobHead = jobTail = 0;
    jobActive = 0;
}

static void
jobs_process(uint32_t diff_us) {
    while (jobHead != jobTail) {
        job_t* j = &jobs[jobHead];
        CO_SDOclient_t* sdo = &CO->SDOclient[0];
        CO_SDO_abortCode_t ab = CO_SDO_AB_NONE;
        if (j->type == J_SDO_W || j->type == J_SDO_R) {
            if (!jobActive) {
                CO_SDOclient_setup(sdo, CO_CAN_ID_SDO_CLI + j->node, CO_CAN_ID_SDO_SRV + j->node, j->node);
                if (j->type == J_SDO_W) {
                    uint8_t buf[4] = {(uint8_t)j->value, (uint8_t)(j->value >> 8), (uint8_t)(j->value >> 16),
                                      (uint8_t)(j->value >> 24)};
                    CO_SDOclientDownloadInitiate(sdo, j->index, j->sub, j->len, SDO_CLI_TIMEOUT_TIME, false);
                    CO_SDOclientDownloadBufWrite(sdo, buf, j->len);
                } else {
                    CO_SDOclientUploadInitiate(sdo, j->index, j->sub, SDO_CLI_TIMEOUT_TIME, false);
                }
                jobActive = 1;
                diff_us = 0;
            }
            CO_SDO_return_t r;
            if (j->type == J_SDO_W) {
                r = CO_SDOclientDownload(sdo, diff_us, false, false, &ab, NULL, NULL);
            } else {
                r = CO_SDOclientUpload(sdo, diff_us, false, &ab, NULL, NULL, NULL);
            }
            if (r > 0) {
                return; /* waiting */
            }
            if (r < 0) {
                logf_("SDO %s node %u %04X:%02X failed, abort %08X", j->type == J_SDO_W ? "write" : "read",
                      j->node, j->index, j->sub, (unsigned)ab);
            } else if (j->type == J_SDO_R) {
                uint8_t buf[8] = {0};
                size_t n = CO_SDOclientUploadBufRead(sdo, buf, sizeof(buf));
                logf_("SDO read node %u %04X:%02X ok, %u bytes, %02X %02X %02X %02X", j->node, j->index, j->sub,
                      (unsigned)n, buf[0], buf[1], buf[2], buf[3]);
            } else {
                logf_("SDO write node %u %04X:%02X = %u ok", j->node, j->index, j->sub, (unsigned)j->value);
            }
            CO_SDOclientClose(sdo);
            jobActive = 0;
        } else if (j->type == J_NMT) {
            logf_("NMT command %02X node %u", (unsigned)j->index, j->node);
            CO_NMT_sendCommand(CO->NMT, (CO_NMT_command_t)j->index, j->node);
        } else if (j->type == J_LOCAL_1016) {
            OD_set_u32(OD_ENTRY_H1016, j->sub, j->value, false);
            logf_("own 1016h:%02X = %08X", j->sub, (unsigned)j->value);
        } else if (j->type == J_GUARD) {
            CO_nodeGuardingMaster_initNode(CO->NGmaster, j->sub, j->node, (uint16_t)j->value);
            logf_("guarding node %u every %u ms", j->node, (unsigned)j->value);
        }
        jobHead = (jobHead + 1) % MAXJOBS;
    }
}

/* master: configure one slave (spec token "Nh" or "Ng", k = its position in --slaves), then start it */
static void
master_queue_slave(int n, char kind, int k) {
    if (kind == 'g') {
        job_add(J_SDO_W, n, 0x1017, 0, 2, 0);   /* no heartbeat: guarding is used */
        job_add(J_SDO_W, n, 0x100C, 0, 2, 100); /* guard time 100 ms */
        job_add(J_SDO_W, n, 0x100D, 0, 1, 3);   /* life time factor 3 */
        job_add(J_NMT, n, CO_NMT_ENTER_OPERATIONAL, 0, 0, 0);
        job_add(J_GUARD, n, 0, k, 0, 100);
    } else {
        job_add(J_SDO_W, n, 0x1016, 1, 4, (1u << 16) | 600u); /* consume master's heartbeat, 600 ms */
        job_add(J_SDO_W, n, 0x1017, 0, 2, 100);               /* producer heartbeat 100 ms */
        job_add(J_NMT, n, CO_NMT_ENTER_OPERATIONAL, 0, 0, 0);
        job_add(J_LOCAL_1016, n, 0x1016, k + 1, 4, ((uint32_t)n << 16) | 300u); /* master consumes N, 300 ms */
    }
}

/* master: configure every slave (or only node `only`, if > 0), then start it */
static void
master_queue_configuration_of(int only) {
    char spec[128];
    strncpy(spec, slavesSpec, sizeof(spec) - 1);
    spec[sizeof(spec) - 1] = 0;
    int k = 0;
    for (char* tok = strtok(spec, ","); tok != NULL; tok = strtok(NULL, ",")) {
        int n = atoi(tok);
        char kind = tok[strlen(tok) - 1];
        if (only <= 0 || only == n) {
            master_queue_slave(n, kind, k);
        }
        k++;
    }
}

static void
master_queue_configuration(void) {
    master_queue_configuration_of(0);
}

/* ------------------------------------------------ ground-truth callbacks */
/* called by the patched stack of dev_syncskip (sync_skip.patch) when it injects its bug */
void nmtcheck_injected(const char* what);
void
nmtcheck_injected(const char* what) {
    logf_("injected (patched stack): %s", what);
}

static const char*
nmt_state_name(CO_NMT_internalState_t state) {
    switch (state) {
        case CO_NMT_INITIALIZING: return "INITIALIZING";
        case CO_NMT_PRE_OPERATIONAL: return "PRE-OPERATIONAL";
        case CO_NMT_OPERATIONAL: return "OPERATIONAL";
        case CO_NMT_STOPPED: return "STOPPED";
        default: return "UNKNOWN";
    }
}

/* called by the patched stack of dev_inhibit (tpdo_inhibit.patch) when it sends a TPDO
 * although its inhibit time has not elapsed */
void nmtcheck_inhibit_bypass(unsigned canId, unsigned leftUs, unsigned inhibitUs);
void
nmtcheck_inhibit_bypass(unsigned canId, unsigned leftUs, unsigned inhibitUs) {
    logf_("injected (patched stack): TPDO %03Xh sent with %u us of its inhibit time %u us left", canId, leftUs,
          inhibitUs);
}

/* called by the patched stack of dev_late (tpdo_late.patch) when it sends a synchronous TPDO
 * after the synchronous window */
void nmtcheck_tpdo_late(unsigned canId, unsigned sinceSyncUs, unsigned windowUs);
void
nmtcheck_tpdo_late(unsigned canId, unsigned sinceSyncUs, unsigned windowUs) {
    logf_("injected (patched stack): TPDO %03Xh sent %u us after the SYNC, %u us after its window 1007h = %u us",
          canId, sinceSyncUs, sinceSyncUs - windowUs, windowUs);
}

/* called by the patched stack of dev_emcyshort (emcy_short.patch) after it sent an EMCY with
 * a DLC other than 8 */
void nmtcheck_emcy_short(unsigned canId, unsigned dlc);
void
nmtcheck_emcy_short(unsigned canId, unsigned dlc) {
    logf_("injected (patched stack): EMCY %03Xh sent with DLC %u instead of 8", canId, dlc);
}

/* the valid PDOs as the object dictionary holds them after CO_CANopenInitPDO() */
static void
log_pdo_configuration(void) {
    const OD_entry_t* entries[] = {OD_ENTRY_H1800, OD_ENTRY_H1801, OD_ENTRY_H1802, OD_ENTRY_H1803,
                                   OD_ENTRY_H1400, OD_ENTRY_H1401, OD_ENTRY_H1402, OD_ENTRY_H1403};
    for (unsigned k = 0; k < 8; k++) {
        OD_entry_t* comm = (OD_entry_t*)entries[k];
        int isTpdo = k < 4;
        OD_entry_t* map = OD_find(OD, (uint16_t)(OD_getIndex(comm) + 0x200U));
        uint32_t cob = 0, m = 0;
        uint8_t type = 0, n = 0;
        uint16_t inhibit = 0, event = 0;
        OD_get_u32(comm, 1, &cob, true);
        if (cob & 0x80000000u) {
            continue; /* not valid */
        }
        OD_get_u8(comm, 2, &type, true);
        if (isTpdo) {
            OD_get_u16(comm, 3, &inhibit, true);
        }
        OD_get_u16(comm, 5, &event, true);
        OD_get_u8(map, 0, &n, true);
        char maps[100] = "";
        size_t len = 0;
        for (uint8_t i = 1; i <= n && i <= 8; i++) {
            OD_get_u32(map, i, &m, true);
            len += (size_t)snprintf(maps + len, sizeof(maps) - len, " %08X", (unsigned)m);
        }
        if (isTpdo) {
            logf_("PDO configuration: TPDO%u COB-ID %08X type %u inhibit %u event %u mapping%s", k + 1,
                  (unsigned)cob, type, inhibit, event, n ? maps : " none");
        } else {
            logf_("PDO configuration: RPDO%u COB-ID %08X type %u event %u mapping%s", k - 3, (unsigned)cob, type,
                  event, n ? maps : " none");
        }
    }
}

static void
on_nmt_changed(CO_NMT_internalState_t state) {
    logf_("NMT state %s (CANopenNode callback)", nmt_state_name(state));
}

static void
on_emcy(const uint16_t ident, const uint16_t errorCode, const uint8_t errorRegister, const uint8_t errorBit,
        const uint32_t infoCode) {
    if (ident == 0U) { /* the stack's own EMCY, just sent */
        logf_("EMCY sent: code %04X register %02X bit %02X info %08X (CANopenNode callback)", errorCode,
              errorRegister, errorBit, (unsigned)infoCode);
    }
}

static void
log_status(void) {
    char bits[256] = "";
    size_t n = 0;
    for (unsigned b = 0; b < CO_CONFIG_EM_ERR_STATUS_BITS_COUNT; b++) {
        if (CO_isError(CO->em, (uint8_t)b) && n + 4 < sizeof(bits)) {
            n += (size_t)snprintf(bits + n, sizeof(bits) - n, " %02X", b);
        }
    }
    logf_("status: NMT state %s, error register %02X, active error bits:%s",
          nmt_state_name(CO_NMT_getInternalState(CO->NMT)), CO_getErrorRegister(CO->em), n ? bits : " none");
}

/* ------------------------------------------------------------ control */
static void
handle_control(char* text) {
    logf_("control: %s", text);
    unsigned a, b, c, d, e;
    if (sscanf(text, "nmt %x %u", &a, &b) == 2) {
        job_add(J_NMT, (int)b, (int)a, 0, 0, 0);
    } else if (sscanf(text, "sdo_read %u %x %x", &a, &b, &c) == 3) {
        job_add(J_SDO_R, (int)a, (int)b, (int)c, 0, 0);
    } else if (sscanf(text, "sdo_write %u %x %x %u %u", &a, &b, &c, &d, &e) == 5) {
        job_add(J_SDO_W, (int)a, (int)b, (int)c, (int)d, e);
    } else if (strncmp(text, "emcy_set", 8) == 0) {
        CO_errorReport(CO->em, CO_EM_MANUFACTURER_START, CO_EMC_DEVICE_SPECIFIC, 0x1234);
    } else if (strncmp(text, "emcy_clear", 10) == 0) {
        CO_errorReset(CO->em, CO_EM_MANUFACTURER_START, 0);
    } else if (sscanf(text, "err_set %x %x %x", &a, &b, &c) == 3) {
        CO_errorReport(CO->em, (uint8_t)a, (uint16_t)b, c);
    } else if (sscanf(text, "err_reset %x %x", &a, &b) == 2) {
        CO_errorReset(CO->em, (uint8_t)a, b);
    } else if (sscanf(text, "tpdo_req %u %u", &a, &b) == 2) {
        tpdoReqLeft = a; /* the main loop asks for the TPDO: first at once, then every b ms */
        tpdoReqGapMs = b;
        tpdoReqNext = 0;
    } else if (strncmp(text, "status", 6) == 0) {
        log_status();
    } else if (sscanf(text, "set1017 %u", &a) == 1) {
        OD_set_u16(OD_ENTRY_H1017, 0, (uint16_t)a, false); /* local write through CANopenNode's OD extension */
    } else if (sscanf(text, "config %u", &a) == 1) {
        /* the master application re-configures and starts one slave (after its boot-up) */
        master_queue_configuration_of((int)a);
    } else if (strncmp(text, "quit", 4) == 0) {
        exit(0);
    } else {
        logf_("unknown control command");
    }
}

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
        } else if (n > 1 && m.raw[0] == 'C') {
            m.raw[n < (ssize_t)sizeof(m.raw) ? n : (ssize_t)sizeof(m.raw) - 1] = 0;
            handle_control(m.raw + 1);
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
        else if (!strcmp(o, "--self-start")) { selfStart = 1; }
        else if (!strcmp(o, "--no-tpdo")) { noTpdo = 1; }
        else if (!strcmp(o, "--master")) { isMaster = 1; }
        else if (!strcmp(o, "--slaves")) { strncpy(slavesSpec, v, sizeof(slavesSpec) - 1); i++; }
        else if (!strcmp(o, "--reset-all")) { resetAll = 1; }
        else if (!strcmp(o, "--reset-delay")) { resetDelayMs = atoi(v); i++; }
        else if (!strcmp(o, "--config-delay")) { configDelayMs = atoi(v); i++; }
        else if (!strcmp(o, "--sync-us")) { syncUs = (unsigned)atoi(v); i++; }
        else if (!strcmp(o, "--sync-cons-us")) { syncConsUs = (unsigned)atoi(v); i++; }
        else if (!strcmp(o, "--sync-ovf")) { syncOvf = atoi(v); i++; }
        else if (!strcmp(o, "--emcy-inhibit")) { emcyInhibit = atoi(v); i++; }
        else if (!strcmp(o, "--sync-window-us")) { syncWindowUs = atoi(v); i++; }
        else if (!strcmp(o, "--guard")) { sscanf(v, "%u:%u", &guardPowerOn, &lifePowerOn); i++; }
        else if (!strcmp(o, "--tpdo1")) {
            if (sscanf(v, "%d:%d:%d", &tpdoType, &tpdoInhibit, &tpdoEvent) != 3) {
                fprintf(stderr, "--tpdo1 TYPE:INHIBIT:EVENT\n");
                return 2;
            }
            i++;
        }
        else if (!strcmp(o, "--rpdo1")) {
            char mapList[128];
            if (sscanf(v, "%x:%u:%u:%127s", &rpdoCob, &rpdoType, &rpdoEvent, mapList) != 4) {
                fprintf(stderr, "--rpdo1 COBID:TYPE:EVENT:MAP[,MAP...]\n");
                return 2;
            }
            for (char* tok = strtok(mapList, ","); tok != NULL && rpdoMapCount < 8; tok = strtok(NULL, ",")) {
                rpdoMap[rpdoMapCount++] = (uint32_t)strtoul(tok, NULL, 16);
            }
            rpdoSet = 1;
            i++;
        }
        else { fprintf(stderr, "unknown option %s\n", o); return 2; }
    }
    if (hubDir == NULL || nodeId < 1 || nodeId > 127) {
        fprintf(stderr, "usage: dev --hub DIR --name NAME --node N [options]\n");
        return 2;
    }

    /* connect to the hub */
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
    /* power-on values of the object dictionary */
    OD_PERSIST_COMM.x1017_producerHeartbeatTime = (uint16_t)hbPowerOn;
    if (noTpdo) {
        OD_PERSIST_COMM.x1800_TPDOCommunicationParameter.COB_IDUsedByTPDO |= 0x80000000u;
    }
    if (guardPowerOn != 0) { /* guarding configured at power-on (stored parameters) */
        OD_RAM.x100C_guardTime = (uint16_t)guardPowerOn;
        OD_RAM.x100D_lifeTimeFactor = (uint8_t)lifePowerOn;
    }
    if (syncUs != 0) { /* SYNC producer at power-on: 1005h bit 30, 1006h */
        OD_PERSIST_COMM.x1005_COB_ID_SYNCMessage = 0x40000080u;
        OD_PERSIST_COMM.x1006_communicationCyclePeriod = syncUs;
    } else if (syncConsUs != 0) { /* SYNC consumer with a timeout at power-on: 1006h only */
        OD_PERSIST_COMM.x1006_communicationCyclePeriod = syncConsUs;
    }
    if (syncOvf >= 0) { /* power-on 1019h */
        OD_PERSIST_COMM.x1019_synchronousCounterOverflowValue = (uint8_t)syncOvf;
    }
    if (syncWindowUs >= 0) { /* power-on 1007h */
        OD_PERSIST_COMM.x1007_synchronousWindowLength = (uint32_t)syncWindowUs;
    }
    if (emcyInhibit >= 0) { /* power-on 1015h */
        OD_PERSIST_COMM.x1015_inhibitTimeEMCY = (uint16_t)emcyInhibit;
    }
    if (tpdoType >= 0) { /* power-on TPDO1 communication parameters (stored) */
        OD_PERSIST_COMM.x1800_TPDOCommunicationParameter.transmissionType = (uint8_t)tpdoType;
        OD_PERSIST_COMM.x1800_TPDOCommunicationParameter.inhibitTime = (uint16_t)tpdoInhibit;
        OD_PERSIST_COMM.x1800_TPDOCommunicationParameter.eventTimer = (uint16_t)tpdoEvent;
    }
    if (rpdoSet) { /* power-on RPDO1 communication and mapping parameters (stored) */
        OD_PERSIST_COMM.x1400_RPDOCommunicationParameter.COB_IDUsedByRPDO = rpdoCob;
        OD_PERSIST_COMM.x1400_RPDOCommunicationParameter.transmissionType = (uint8_t)rpdoType;
        OD_PERSIST_COMM.x1400_RPDOCommunicationParameter.eventTimer = (uint16_t)rpdoEvent;
        for (unsigned k = 0; k < rpdoMapCount; k++) {
            OD_set_u32(OD_ENTRY_H1600, (uint8_t)(k + 1), rpdoMap[k], true);
        }
        OD_PERSIST_COMM.x1600_RPDOMappingParameter.numberOfMappedApplicationObjectsInPDO = (uint8_t)rpdoMapCount;
    }
    uint16_t nmtControl = CO_NMT_ERR_ON_ERR_REG | CO_ERR_REG_GENERIC_ERR | CO_ERR_REG_COMMUNICATION;
    if (selfStart || isMaster) {
        nmtControl |= CO_NMT_STARTUP_TO_OPERATIONAL;
    }

    CO_NMT_reset_cmd_t reset = CO_RESET_NOT;
    while (reset != CO_RESET_APP && reset != CO_RESET_QUIT) {
        logf_("communication reset");
        CO->CANmodule->CANnormal = false;
        CO_CANsetConfigurationMode((void*)&hubFd);
        CO_CANmodule_disable(CO->CANmodule);
        if (CO_CANinit(CO, (void*)&hubFd, 0) != CO_ERROR_NO) {
            fprintf(stderr, "CO_CANinit failed\n");
            return 1;
        }
        uint32_t errInfo = 0;
        CO_ReturnError_t err = CO_CANopenInit(CO, NULL, NULL, OD, NULL, nmtControl, FIRST_HB_TIME,
                                              SDO_SRV_TIMEOUT_TIME, SDO_CLI_TIMEOUT_TIME, false, (uint8_t)nodeId,
                                              &errInfo);
        if (err != CO_ERROR_NO) {
            fprintf(stderr, "CO_CANopenInit failed %d (OD %04X)\n", err, (unsigned)errInfo);
            return 1;
        }
        err = CO_CANopenInitPDO(CO, CO->em, OD, (uint8_t)nodeId, &errInfo);
        if (err != CO_ERROR_NO) {
            fprintf(stderr, "CO_CANopenInitPDO failed %d (OD %04X)\n", err, (unsigned)errInfo);
            return 1;
        }
        CO_NMT_initCallbackChanged(CO->NMT, on_nmt_changed); /* prints the current state too */
        CO_EM_initCallbackRx(CO->em, on_emcy);
        log_pdo_configuration();
        CO_CANsetNormalMode(CO->CANmodule);
        jobs_clear();
        int configQueued = 0;
        uint64_t tBoot = now_us(), last = tBoot, nextCount = tBoot + 500000u;
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
                break; /* NMT reset command: re-initialise at once */
            }
            bool_t syncWas = CO_process_SYNC(CO, diff, NULL);
            CO_process_RPDO(CO, syncWas, diff, NULL);
            CO_process_TPDO(CO, syncWas, diff, NULL);

            /* application */
            if (t >= nextCount) { /* 2000h counter, mapped to TPDO1 */
                OD_RAM.x2000_counter++;
                nextCount += 500000u;
            }
            if (tpdoReqLeft > 0 && t >= tpdoReqNext) { /* control tpdo_req: a new value, sent by event */
                OD_RAM.x2000_counter++;
                CO_TPDOsendRequest(&CO->TPDO[0]);
                tpdoReqLeft--;
                tpdoReqNext = t + (uint64_t)tpdoReqGapMs * 1000u;
                logf_("application: 2000h = %u, TPDO1 requested (CO_TPDOsendRequest, request %u)",
                      (unsigned)OD_RAM.x2000_counter, ++tpdoReqNo);
            }
            if (isMaster) {
                uint64_t sinceBoot_ms = (t - tBoot) / 1000u;
                if (resetAll && !resetAllDone) {
                    if (sinceBoot_ms >= (uint64_t)resetDelayMs) {
                        resetAllDone = 1;
                        logf_("NMT reset communication, all nodes");
                        CO_NMT_sendCommand(CO->NMT, CO_NMT_RESET_COMMUNICATION, 0);
                    }
                } else if (!configQueued && sinceBoot_ms >= (uint64_t)configDelayMs) {
                    configQueued = 1;
                    master_queue_configuration();
                }
            }
            jobs_process(diff);
        }
    }
    logf_("reset node: restarting the program (power-on values)");
    CO_delete(CO);
    close(hubFd);
    if (reset == CO_RESET_APP) {
        execv("/proc/self/exe", argv);
        perror("execv");
    }
    return 0;
}
