/* STM32 HAL glue for the bridge firmware: TIM3 PWM, UART at 115200 baud, watchdog on SysTick.
 *
 * Boards (pick one with -D):
 *   BRIDGE_BLUEPILL  STM32F103C8: 8 MHz HSE x 9 = 72 MHz; TIM3 clock 72 MHz (APB1 36 MHz x 2);
 *                    USART1 on PA9 (TX) / PA10 (RX) through a USB-serial adapter.
 *   BRIDGE_NUCLEO    Nucleo-F401RE: 16 MHz HSI -> 84 MHz; TIM3 clock 84 MHz (APB1 42 MHz x 2);
 *                    USART2 on PA2 / PA3, the ST-LINK virtual COM port (/dev/ttyACM0).
 * TIM3 channels 1..4 are PA6, PA7, PB0, PB1 on both. The timer runs at
 *
 *     f_PWM = f_TIM / ((PSC + 1)(ARR + 1))
 *
 * with PSC, ARR and f_TIM from bridge_rig.h: the rig file's psc, arr and timer_clock_hz must
 * be the same numbers (72 MHz, PSC 0, ARR 799 -> 90 kHz on the Blue Pill; build the Nucleo
 * with -DBRIDGE_TIMER_CLOCK_HZ=84000000u and put 84000000 in the rig file).
 * HAL_GetTick() counts SysTick milliseconds (HAL_IncTick below); the main loop hands it to
 * the core, whose watchdog puts every channel at neutral when the host falls silent. Bytes
 * arrive by interrupt into a ring buffer, so a reply being sent loses no input.
 * For USB CDC instead of a UART (a Blue Pill's own USB port), call rx_push() from the CDC
 * receive callback and send with CDC_Transmit_FS() in write_bytes(). */
#if defined(BRIDGE_BLUEPILL)
#include "stm32f1xx_hal.h"
#define BRIDGE_UART USART1
#define BRIDGE_UART_IRQn USART1_IRQn
#elif defined(BRIDGE_NUCLEO)
#include "stm32f4xx_hal.h"
#define BRIDGE_UART USART2
#define BRIDGE_UART_IRQn USART2_IRQn
#else
#error "define BRIDGE_BLUEPILL or BRIDGE_NUCLEO"
#endif

#include "../bridge_core.h"
#include "../bridge_rig.h"

#define RX_SIZE 256u  /* power of two */

static UART_HandleTypeDef huart;
static TIM_HandleTypeDef htim;
static uint8_t rx_byte;
static volatile uint8_t rx_buf[RX_SIZE];
static volatile uint32_t rx_head, rx_tail;

static const uint32_t tim_channels[BRIDGE_MAX_CHANNELS] = {TIM_CHANNEL_1, TIM_CHANNEL_2,
                                                           TIM_CHANNEL_3, TIM_CHANNEL_4};

static void rx_push(uint8_t byte)
{
    if (rx_head - rx_tail < RX_SIZE) {  /* full: the byte is dropped, the line then garbled */
        rx_buf[rx_head % RX_SIZE] = byte;
        rx_head++;
    }
}

static void set_compare(void *ctx, uint8_t ch, uint32_t ccr)
{
    (void)ctx;
    __HAL_TIM_SET_COMPARE(&htim, tim_channels[ch - 1u], ccr);
}

static void write_bytes(void *ctx, const char *bytes, size_t n)
{
    (void)ctx;
    HAL_UART_Transmit(&huart, (uint8_t *)bytes, (uint16_t)n, 100u);
}

void SysTick_Handler(void)
{
    HAL_IncTick();
}

#if defined(BRIDGE_BLUEPILL)
void USART1_IRQHandler(void)
#else
void USART2_IRQHandler(void)
#endif
{
    HAL_UART_IRQHandler(&huart);
}

void HAL_UART_RxCpltCallback(UART_HandleTypeDef *h)
{
    rx_push(rx_byte);
    HAL_UART_Receive_IT(h, &rx_byte, 1u);
}

void HAL_UART_ErrorCallback(UART_HandleTypeDef *h)
{
    HAL_UART_Receive_IT(h, &rx_byte, 1u);  /* overrun or noise: keep receiving */
}

static void fail(void)
{
    __disable_irq();
    for (;;) {
    }
}

static void clock_init(void)
{
    RCC_OscInitTypeDef osc = {0};
    RCC_ClkInitTypeDef clk = {0};
#if defined(BRIDGE_BLUEPILL)
    osc.OscillatorType = RCC_OSCILLATORTYPE_HSE;
    osc.HSEState = RCC_HSE_ON;
    osc.HSEPredivValue = RCC_HSE_PREDIV_DIV1;
    osc.PLL.PLLState = RCC_PLL_ON;
    osc.PLL.PLLSource = RCC_PLLSOURCE_HSE;
    osc.PLL.PLLMUL = RCC_PLL_MUL9;  /* 72 MHz */
    if (HAL_RCC_OscConfig(&osc) != HAL_OK) {
        fail();
    }
    clk.ClockType = RCC_CLOCKTYPE_SYSCLK | RCC_CLOCKTYPE_HCLK | RCC_CLOCKTYPE_PCLK1 | RCC_CLOCKTYPE_PCLK2;
    clk.SYSCLKSource = RCC_SYSCLKSOURCE_PLLCLK;
    clk.AHBCLKDivider = RCC_SYSCLK_DIV1;
    clk.APB1CLKDivider = RCC_HCLK_DIV2;  /* 36 MHz; timers x2 = 72 MHz */
    clk.APB2CLKDivider = RCC_HCLK_DIV1;
    if (HAL_RCC_ClockConfig(&clk, FLASH_LATENCY_2) != HAL_OK) {
        fail();
    }
#else
    __HAL_RCC_PWR_CLK_ENABLE();
    __HAL_PWR_VOLTAGESCALING_CONFIG(PWR_REGULATOR_VOLTAGE_SCALE2);
    osc.OscillatorType = RCC_OSCILLATORTYPE_HSI;
    osc.HSIState = RCC_HSI_ON;
    osc.HSICalibrationValue = RCC_HSICALIBRATION_DEFAULT;
    osc.PLL.PLLState = RCC_PLL_ON;
    osc.PLL.PLLSource = RCC_PLLSOURCE_HSI;
    osc.PLL.PLLM = 16u;
    osc.PLL.PLLN = 336u;
    osc.PLL.PLLP = RCC_PLLP_DIV4;  /* 84 MHz */
    osc.PLL.PLLQ = 7u;
    if (HAL_RCC_OscConfig(&osc) != HAL_OK) {
        fail();
    }
    clk.ClockType = RCC_CLOCKTYPE_SYSCLK | RCC_CLOCKTYPE_HCLK | RCC_CLOCKTYPE_PCLK1 | RCC_CLOCKTYPE_PCLK2;
    clk.SYSCLKSource = RCC_SYSCLKSOURCE_PLLCLK;
    clk.AHBCLKDivider = RCC_SYSCLK_DIV1;
    clk.APB1CLKDivider = RCC_HCLK_DIV2;  /* 42 MHz; timers x2 = 84 MHz */
    clk.APB2CLKDivider = RCC_HCLK_DIV1;
    if (HAL_RCC_ClockConfig(&clk, FLASH_LATENCY_2) != HAL_OK) {
        fail();
    }
#endif
}

static void pins_init(void)
{
    GPIO_InitTypeDef pin = {0};
    __HAL_RCC_GPIOA_CLK_ENABLE();
    __HAL_RCC_GPIOB_CLK_ENABLE();
    pin.Mode = GPIO_MODE_AF_PP;
    pin.Speed = GPIO_SPEED_FREQ_HIGH;
#if defined(BRIDGE_NUCLEO)
    pin.Alternate = GPIO_AF2_TIM3;
#endif
    pin.Pin = GPIO_PIN_6 | GPIO_PIN_7;
    HAL_GPIO_Init(GPIOA, &pin);
    pin.Pin = GPIO_PIN_0 | GPIO_PIN_1;
    HAL_GPIO_Init(GPIOB, &pin);
#if defined(BRIDGE_BLUEPILL)
    pin.Pin = GPIO_PIN_9;  /* USART1 TX; RX (PA10) stays an input */
    HAL_GPIO_Init(GPIOA, &pin);
#else
    pin.Pin = GPIO_PIN_2 | GPIO_PIN_3;
    pin.Pull = GPIO_PULLUP;
    pin.Alternate = GPIO_AF7_USART2;
    HAL_GPIO_Init(GPIOA, &pin);
#endif
}

static void timer_init(void)
{
    TIM_OC_InitTypeDef oc = {0};
    uint32_t i;
    __HAL_RCC_TIM3_CLK_ENABLE();
    htim.Instance = TIM3;
    htim.Init.Prescaler = BRIDGE_PSC;
    htim.Init.Period = BRIDGE_ARR;
    htim.Init.CounterMode = TIM_COUNTERMODE_UP;
    htim.Init.ClockDivision = TIM_CLOCKDIVISION_DIV1;
    htim.Init.AutoReloadPreload = TIM_AUTORELOAD_PRELOAD_ENABLE;
    if (HAL_TIM_PWM_Init(&htim) != HAL_OK) {
        fail();
    }
    oc.OCMode = TIM_OCMODE_PWM1;
    oc.Pulse = BRIDGE_NEUTRAL_CCR;  /* neutral from the first period on */
    oc.OCPolarity = TIM_OCPOLARITY_HIGH;
    for (i = 0; i < BRIDGE_CHANNELS; i++) {
        if (HAL_TIM_PWM_ConfigChannel(&htim, &oc, tim_channels[i]) != HAL_OK ||
            HAL_TIM_PWM_Start(&htim, tim_channels[i]) != HAL_OK) {
            fail();
        }
    }
}

static void uart_init(void)
{
#if defined(BRIDGE_BLUEPILL)
    __HAL_RCC_USART1_CLK_ENABLE();
#else
    __HAL_RCC_USART2_CLK_ENABLE();
#endif
    huart.Instance = BRIDGE_UART;
    huart.Init.BaudRate = 115200u;
    huart.Init.WordLength = UART_WORDLENGTH_8B;
    huart.Init.StopBits = UART_STOPBITS_1;
    huart.Init.Parity = UART_PARITY_NONE;
    huart.Init.Mode = UART_MODE_TX_RX;
    huart.Init.HwFlowCtl = UART_HWCONTROL_NONE;
    huart.Init.OverSampling = UART_OVERSAMPLING_16;
    if (HAL_UART_Init(&huart) != HAL_OK) {
        fail();
    }
    HAL_NVIC_SetPriority(BRIDGE_UART_IRQn, 1u, 0u);
    HAL_NVIC_EnableIRQ(BRIDGE_UART_IRQn);
    HAL_UART_Receive_IT(&huart, &rx_byte, 1u);
}

int main(void)
{
    static bridge b;
    const bridge_config cfg = {BRIDGE_TIMER_CLOCK_HZ, BRIDGE_PSC, BRIDGE_ARR, BRIDGE_NEUTRAL_CCR,
                               BRIDGE_WATCHDOG_MS, 0u, BRIDGE_CHANNELS, BRIDGE_CCR_MIN,
                               BRIDGE_CCR_MAX};
    const bridge_hooks hooks = {set_compare, write_bytes, NULL, NULL};

    HAL_Init();  /* SysTick at 1 kHz */
    clock_init();
    pins_init();
    timer_init();
    if (bridge_init(&b, &cfg, &hooks, HAL_GetTick()) != 0) {
        fail();
    }
    uart_init();
    for (;;) {
        while (rx_tail != rx_head) {
            uint8_t byte = rx_buf[rx_tail % RX_SIZE];
            rx_tail++;
            bridge_feed(&b, &byte, 1u, HAL_GetTick());
        }
        bridge_tick(&b, HAL_GetTick());
    }
}
