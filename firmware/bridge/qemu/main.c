/* Bare-metal STM32F405 build of the bridge firmware, register level, no ST HAL: runs on
 * `qemu-system-arm -M netduinoplus2` and on a real F405 (set TIM2_CLOCK_HZ to its timer clock).
 *
 * USART1 (PA9 TX, PA10 RX, AF7) carries the protocol; TIM3 channels 1..4 (PA6, PA7, PB0,
 * PB1, AF2) make the PWM with the rig's PSC/ARR (bridge_rig.h). The watchdog's milliseconds
 * come from free-running 32-bit TIM2 at 1 MHz, read when needed: QEMU delivers SysTick
 * interrupts late on a loaded host and a counted tick then loses time (measured here: half
 * the ticks), while a timer's counter follows the clock. USART1 is polled: the host sends one line and waits for its reply, so
 * the receive register is read long before the next byte (the HAL glue uses an interrupt). */
#include <stdint.h>

#include "../bridge_core.h"
#include "../bridge_rig.h"

#ifndef TIM2_CLOCK_HZ
#define TIM2_CLOCK_HZ 1000000000u  /* QEMU's timer model clock; 16 MHz on a bare F405 after reset */
#endif
#ifndef USART_BRR
#define USART_BRR 0x2D9u  /* 115200 baud from the 84 MHz APB2 clock */
#endif

#define REG(addr) (*(volatile uint32_t *)(addr))

#define RCC_AHB1ENR REG(0x40023830u)
#define RCC_APB1ENR REG(0x40023840u)
#define RCC_APB2ENR REG(0x40023844u)
#define GPIOA_MODER REG(0x40020000u)
#define GPIOA_AFRL REG(0x40020020u)
#define GPIOA_AFRH REG(0x40020024u)
#define GPIOB_MODER REG(0x40020400u)
#define GPIOB_AFRL REG(0x40020420u)

#define USART1_SR REG(0x40011000u)
#define USART1_DR REG(0x40011004u)
#define USART1_BRR REG(0x40011008u)
#define USART1_CR1 REG(0x4001100Cu)
#define USART_SR_RXNE (1u << 5)
#define USART_SR_TXE (1u << 7)
#define USART_CR1_UE (1u << 13)
#define USART_CR1_TE (1u << 3)
#define USART_CR1_RE (1u << 2)

#define TIM3_BASE 0x40000400u
#define TIM3_CR1 REG(TIM3_BASE + 0x00u)
#define TIM3_EGR REG(TIM3_BASE + 0x14u)
#define TIM3_CCMR1 REG(TIM3_BASE + 0x18u)
#define TIM3_CCMR2 REG(TIM3_BASE + 0x1Cu)
#define TIM3_CCER REG(TIM3_BASE + 0x20u)
#define TIM3_PSC REG(TIM3_BASE + 0x28u)
#define TIM3_ARR REG(TIM3_BASE + 0x2Cu)
#define TIM3_CCR(ch) REG(TIM3_BASE + 0x30u + 4u * (uint32_t)(ch))  /* ch 1..4: 0x34..0x40 */
#define TIM_PWM1_PRELOAD 0x68u  /* OCxM = 110 (PWM mode 1), OCxPE */

#define TIM2_CR1 REG(0x40000000u)
#define TIM2_EGR REG(0x40000014u)
#define TIM2_CNT REG(0x40000024u)
#define TIM2_PSC REG(0x40000028u)
#define TIM2_ARR REG(0x4000002Cu)

void systick_handler(void)
{
}

/* Milliseconds since boot, from TIM2's microsecond count (wraps every 71 minutes; call at
 * least that often). */
static uint32_t now_ms(void)
{
    static uint32_t last_us, pending_us, ms;
    uint32_t us = TIM2_CNT;
    pending_us += us - last_us;
    last_us = us;
    ms += pending_us / 1000u;
    pending_us %= 1000u;
    return ms;
}

static void set_compare(void *ctx, uint8_t ch, uint32_t ccr)
{
    (void)ctx;
    TIM3_CCR(ch) = ccr;
}

static void write_bytes(void *ctx, const char *bytes, size_t n)
{
    (void)ctx;
    while (n-- > 0u) {
        while ((USART1_SR & USART_SR_TXE) == 0u) {
        }
        USART1_DR = (uint8_t)*bytes++;
    }
}

static void pins_init(void)
{
    RCC_AHB1ENR |= (1u << 0) | (1u << 1);  /* GPIOA, GPIOB */
    /* PA6, PA7 AF2 (TIM3 CH1, CH2); PA9, PA10 AF7 (USART1) */
    GPIOA_MODER = (GPIOA_MODER & ~((3u << 12) | (3u << 14) | (3u << 18) | (3u << 20))) |
                  (2u << 12) | (2u << 14) | (2u << 18) | (2u << 20);
    GPIOA_AFRL = (GPIOA_AFRL & ~((0xFu << 24) | (0xFu << 28))) | (2u << 24) | (2u << 28);
    GPIOA_AFRH = (GPIOA_AFRH & ~((0xFu << 4) | (0xFu << 8))) | (7u << 4) | (7u << 8);
    /* PB0, PB1 AF2 (TIM3 CH3, CH4) */
    GPIOB_MODER = (GPIOB_MODER & ~0xFu) | (2u << 0) | (2u << 2);
    GPIOB_AFRL = (GPIOB_AFRL & ~0xFFu) | (2u << 0) | (2u << 4);
}

/* f_PWM = f_TIM / ((PSC + 1)(ARR + 1)); every channel starts at neutral (bridge_init). */
static void timer_init(void)
{
    RCC_APB1ENR |= 1u << 1;  /* TIM3 */
    TIM3_PSC = BRIDGE_PSC;
    TIM3_ARR = BRIDGE_ARR;
    TIM3_CCMR1 = TIM_PWM1_PRELOAD | (TIM_PWM1_PRELOAD << 8);
    TIM3_CCMR2 = TIM_PWM1_PRELOAD | (TIM_PWM1_PRELOAD << 8);
    TIM3_CCER = (1u << 0) | (1u << 4) | (1u << 8) | (1u << 12);
    TIM3_EGR = 1u;  /* load PSC/ARR now */
    TIM3_CR1 = (1u << 7) | 1u;  /* ARPE, CEN */
}

static void usart_init(void)
{
    RCC_APB2ENR |= 1u << 4;  /* USART1 */
    USART1_BRR = USART_BRR;
    USART1_CR1 = USART_CR1_UE | USART_CR1_TE | USART_CR1_RE;
}

static void clock_init(void)
{
    RCC_APB1ENR |= 1u << 0;  /* TIM2 */
    TIM2_PSC = TIM2_CLOCK_HZ / 1000000u - 1u;
    TIM2_ARR = 0xFFFFFFFFu;
    TIM2_EGR = 1u;
    TIM2_CR1 = 1u;
}

int main(void)
{
    static bridge b;
    const bridge_config cfg = {BRIDGE_TIMER_CLOCK_HZ, BRIDGE_PSC, BRIDGE_ARR, BRIDGE_NEUTRAL_CCR,
                               BRIDGE_WATCHDOG_MS, 0u, BRIDGE_CHANNELS, BRIDGE_CCR_MIN,
                               BRIDGE_CCR_MAX};
    const bridge_hooks hooks = {set_compare, write_bytes, NULL, NULL};

    pins_init();
    timer_init();
    clock_init();
    if (bridge_init(&b, &cfg, &hooks, now_ms()) != 0) {
        for (;;) {
        }
    }
    usart_init();
    for (;;) {
        if ((USART1_SR & USART_SR_RXNE) != 0u) {
            uint8_t byte = (uint8_t)USART1_DR;
            bridge_feed(&b, &byte, 1u, now_ms());
        }
        bridge_tick(&b, now_ms());
    }
}
