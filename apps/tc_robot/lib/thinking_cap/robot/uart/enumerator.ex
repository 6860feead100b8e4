defmodule ThinkingCap.Robot.UART.Enumerator do
  @moduledoc false
  # The serial ports that exist, with what sysfs says about each.

  @patterns ~w(/dev/ttyS* /dev/ttyUSB* /dev/ttyACM* /dev/ttyAMA* /dev/ttyXRUSB*
               /dev/ttymxc* /dev/ttyTHS* /dev/ttySAC* /dev/rfcomm*)

  @spec enumerate() :: %{String.t() => map()}
  def enumerate do
    ports =
      @patterns
      |> Enum.flat_map(&Path.wildcard/1)
      |> Enum.filter(&present?/1)
      |> Map.new(&{&1, info(&1)})

    links =
      for link <- Path.wildcard("/dev/serial/by-id/*"),
          target = realpath(link),
          File.exists?(target),
          into: %{},
          do: {link, Map.put(info(target), :target, target)}

    Map.merge(ports, links)
  end

  # /dev/ttyS0..31 exist whether or not there is a UART behind them; sysfs
  # says "type 0" (unknown port) for the absent ones.
  defp present?(path) do
    name = Path.basename(path)

    File.exists?(path) and
      case File.read("/sys/class/tty/#{name}/type") do
        {:ok, type} -> String.trim(type) != "0"
        {:error, _} -> true
      end
  end

  defp info(path) do
    device = realpath("/sys/class/tty/#{Path.basename(path)}/device")

    %{}
    |> put(:driver, driver(device))
    |> Map.merge(usb_info(device))
    |> describe()
  end

  # The device's driver; on newer kernels a UART's device is a "port" of
  # the serial-base bus, and the hardware's driver is a parent's.
  defp driver(nil), do: nil

  defp driver(device) do
    device
    |> ancestors()
    |> Enum.find_value(fn dir ->
      if link_name("#{dir}/subsystem") != "serial-base", do: link_name("#{dir}/driver")
    end)
  end

  defp describe(%{description: _} = info), do: info
  defp describe(%{driver: driver} = info), do: Map.put(info, :description, driver)
  defp describe(info), do: info

  # the USB device is the nearest parent directory with an idVendor
  defp usb_info(nil), do: %{}

  defp usb_info(dir) do
    case Enum.find(ancestors(dir), &File.exists?(Path.join(&1, "idVendor"))) do
      nil ->
        %{}

      usb ->
        %{}
        |> put(:vendor_id, read(usb, "idVendor"))
        |> put(:product_id, read(usb, "idProduct"))
        |> put(:manufacturer, read(usb, "manufacturer"))
        |> put(:description, read(usb, "product"))
        |> put(:serial_number, read(usb, "serial"))
    end
  end

  defp ancestors("/"), do: []
  defp ancestors(dir), do: [dir | ancestors(Path.dirname(dir))]

  defp read(dir, file) do
    case File.read(Path.join(dir, file)) do
      {:ok, text} -> String.trim(text)
      _ -> nil
    end
  end

  defp link_name(path) do
    case File.read_link(path) do
      {:ok, target} -> Path.basename(target)
      _ -> nil
    end
  end

  defp put(map, _key, nil), do: map
  defp put(map, key, value), do: Map.put(map, key, value)

  # The canonical path with every symlink resolved; nil when it does not exist.
  defp realpath(path), do: resolve(Path.split(Path.expand(path)), "/", 0)

  defp resolve(_parts, _dir, depth) when depth > 40, do: nil
  defp resolve([], dir, _depth), do: dir
  defp resolve(["/" | rest], _dir, depth), do: resolve(rest, "/", depth)

  defp resolve([part | rest], dir, depth) do
    path = Path.join(dir, part)

    case File.read_link(path) do
      {:ok, target} -> resolve(Path.split(Path.expand(target, dir)) ++ rest, "/", depth + 1)
      {:error, :einval} -> resolve(rest, path, depth)
      {:error, _} -> nil
    end
  end
end
