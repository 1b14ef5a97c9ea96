/*
 * CO_driver_target.h for the nmtcheck CANopenNode recordings: a userspace
 * "CAN controller" that exchanges frames with hub.py over a UNIX datagram
 * socket (no SocketCAN needed).
 *
 * Written for nmtcheck after CANopenNode's example/CO_driver_target.h
 * (Copyright Janez Paternoster, Apache License 2.0); same structure, our own
 * receive-message type and locking (single-threaded, so the locks are empty).
 */
#ifndef CO_DRIVER_TARGET_H
#define CO_DRIVER_TARGET_H

#include <stddef.h>
#include <stdbool.h>
#include <stdint.h>
#include <string.h>

#ifdef __cplusplus
extern "C" {
#endif

/* Stack configuration (overrides of 301/CO_config.h) */
#define CO_CONFIG_NMT            (CO_CONFIG_NMT_MASTER | CO_CONFIG_NMT_CALLBACK_CHANGE)
/* EMCY producer with 1015h inhibit time and CANopenNode's EMCY callback (dev.c prints the
 * stack's own EMCYs from it); 1015h is 0 at power-on, so EMCYs leave at once as before */
#define CO_CONFIG_EM             (CO_CONFIG_EM_PRODUCER | CO_CONFIG_EM_PROD_INHIBIT | CO_CONFIG_EM_HISTORY \
                                  | CO_CONFIG_EM_CONSUMER)
#define CO_CONFIG_SDO_CLI        (CO_CONFIG_SDO_CLI_ENABLE)
#define CO_CONFIG_FIFO           (CO_CONFIG_FIFO_ENABLE)
#define CO_CONFIG_NODE_GUARDING  (CO_CONFIG_NODE_GUARDING_SLAVE_ENABLE | CO_CONFIG_NODE_GUARDING_MASTER_ENABLE)
#define CO_CONFIG_NODE_GUARDING_MASTER_COUNT 8
#ifdef NMTCHECK_LSS /* lss_dev (lss/ recordings): LSS slave, its direct fastscan answer, LSS master */
#define CO_CONFIG_LSS            (CO_CONFIG_LSS_SLAVE | CO_CONFIG_LSS_SLAVE_FASTSCAN_DIRECT_RESPOND \
                                  | CO_CONFIG_LSS_MASTER)
#else
#define CO_CONFIG_LSS            (0)
#endif
#define CO_CONFIG_LEDS           (0)
#define CO_CONFIG_STORAGE        (0)
#define CO_CONFIG_GTW            (0)
#define CO_CONFIG_HB_CONS        (CO_CONFIG_HB_CONS_ENABLE | CO_CONFIG_FLAG_OD_DYNAMIC)

#define CO_LITTLE_ENDIAN
#define CO_SWAP_16(x) x
#define CO_SWAP_32(x) x
#define CO_SWAP_64(x) x
typedef uint_fast8_t bool_t;
typedef float float32_t;
typedef double float64_t;

/* received CAN frame as passed to the rx callbacks */
typedef struct {
    uint16_t ident; /* 11-bit CAN-ID */
    uint8_t rtr;
    uint8_t DLC;
    uint8_t data[8];
} CO_CANrxMsg_t;

#define CO_CANrxMsg_readIdent(msg) ((uint16_t)(((const CO_CANrxMsg_t*)(msg))->ident))
#define CO_CANrxMsg_readDLC(msg)   ((uint8_t)(((const CO_CANrxMsg_t*)(msg))->DLC))
#define CO_CANrxMsg_readData(msg)  ((const uint8_t*)(((const CO_CANrxMsg_t*)(msg))->data))

typedef struct {
    uint16_t ident; /* bit 11 = RTR */
    uint16_t mask;
    void* object;
    void (*CANrx_callback)(void* object, void* message);
} CO_CANrx_t;

typedef struct {
    uint32_t ident; /* bits 0..10 CAN-ID, bit 15 RTR */
    uint8_t DLC;
    uint8_t data[8];
    volatile bool_t bufferFull;
    volatile bool_t syncFlag;
} CO_CANtx_t;

typedef struct {
    void* CANptr; /* points to the device's hub connection (int fd) */
    CO_CANrx_t* rxArray;
    uint16_t rxSize;
    CO_CANtx_t* txArray;
    uint16_t txSize;
    uint16_t CANerrorStatus;
    volatile bool_t CANnormal;
    volatile bool_t useCANrxFilters;
    volatile bool_t bufferInhibitFlag;
    volatile bool_t firstCANtxMessage;
    volatile uint16_t CANtxCount;
    uint32_t errOld;
} CO_CANmodule_t;

typedef struct {
    void* addr;
    size_t len;
    uint8_t subIndexOD;
    uint8_t attr;
    void* addrNV;
} CO_storage_entry_t;

#define CO_LOCK_CAN_SEND(CAN_MODULE)
#define CO_UNLOCK_CAN_SEND(CAN_MODULE)
#define CO_LOCK_EMCY(CAN_MODULE)
#define CO_UNLOCK_EMCY(CAN_MODULE)
#define CO_LOCK_OD(CAN_MODULE)
#define CO_UNLOCK_OD(CAN_MODULE)

#define CO_MemoryBarrier()
#define CO_FLAG_READ(rxNew) ((rxNew) != NULL)
#define CO_FLAG_SET(rxNew)                                                                                             \
    {                                                                                                                  \
        CO_MemoryBarrier();                                                                                            \
        rxNew = (void*)1L;                                                                                             \
    }
#define CO_FLAG_CLEAR(rxNew)                                                                                           \
    {                                                                                                                  \
        CO_MemoryBarrier();                                                                                            \
        rxNew = NULL;                                                                                                  \
    }

/* hub wire format (shared with hub.py): 16 bytes, little endian */
typedef struct {
    uint8_t type; /* 'F' frame, 'H' hello (data = name), 'C' control (text follows) */
    uint8_t rtr;
    uint8_t dlc;
    uint8_t pad;
    uint32_t id;
    uint8_t data[8];
} hub_frame_t;

/* deliver one frame received from the hub to the stack (CO_driver.c) */
void CO_CANrxFromHub(CO_CANmodule_t* CANmodule, const hub_frame_t* f);

#ifdef __cplusplus
}
#endif

#endif /* CO_DRIVER_TARGET_H */
